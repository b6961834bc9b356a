"""phri.Deformation (eq. 7) against a plain numpy reference, and its contracts."""

from __future__ import annotations

import numpy as np
import pytest

import phri
from phri.exceptions import InvalidParameterError, NonFiniteError, PhriError, ShapeError

NORMS = ("acceleration", "jerk")
END_RULES = ("skip", "shrink")
STENCILS = {"acceleration": (1.0, -2.0, 1.0), "jerk": (-1.0, 3.0, -3.0, 1.0)}


def reference_shape(norm: str, m: int) -> np.ndarray:
    """H = solve(AᵀA, e₁) rescaled to ‖H‖ = √m, with the zero-padded difference matrix A built densely."""
    stencil = STENCILS[norm]
    a = np.zeros((m + len(stencil) - 1, m))
    for k in range(m):
        a[k : k + len(stencil), k] = stencil
    x = np.linalg.solve(a.T @ a, np.eye(m)[0])
    return x * np.sqrt(m) / np.linalg.norm(x)


def reference_window(window: int, end_rule: str, index: int, n_waypoints: int) -> int:
    room = max(n_waypoints - 2 - index, 0)  # waypoints strictly between the current one and the goal
    if room >= window:
        return window
    return room if end_rule == "shrink" else 0


def reference_deform(
    trajectory: np.ndarray, index: int, u_h: np.ndarray, window: int, mu: float, norm: str, end_rule: str
) -> np.ndarray:
    out = trajectory.copy()
    m = reference_window(window, end_rule, index, len(trajectory))
    if m:
        out[index + 1 : index + 1 + m] += mu * np.outer(reference_shape(norm, m), u_h)
    return out


def closed_form(norm: str, m: int) -> np.ndarray:
    """The exact shape: a cubic (acceleration) or quintic (jerk) in the waypoint index."""
    k = np.arange(m, dtype=float)
    if norm == "acceleration":
        h = (k + 1) * (m - k) * (m + 1 - k)
    else:
        h = (k + 1) * (k + 2) * (m - k) * (m + 1 - k) * (m + 2 - k)
    return h * np.sqrt(m) / np.linalg.norm(h)


def test_original_shape_and_defaults() -> None:
    d = phri.Deformation()
    assert (d.window, d.mu, d.norm, d.end_rule) == (5, 0.01, "acceleration", "skip")
    np.testing.assert_allclose(d.shape, [1.0031, 1.3375, 1.2038, 0.8025, 0.3344], atol=5e-5)
    assert repr(d) == "Deformation(window=5, mu=0.01, norm='acceleration', end_rule='skip')"


@pytest.mark.parametrize("norm", NORMS)
@pytest.mark.parametrize("end_rule", END_RULES)
def test_agrees_with_numpy_reference(norm: str, end_rule: str, rng: np.random.Generator) -> None:
    for _ in range(200):
        window = int(rng.integers(1, 25))
        mu = float(rng.choice([-1.0, 1.0]) * rng.uniform(1e-3, 0.1))
        n_waypoints = int(rng.integers(1, 45))
        dof = int(rng.integers(1, 8))
        trajectory = rng.uniform(-np.pi, np.pi, (n_waypoints, dof))
        u_h = rng.uniform(-10.0, 10.0, dof)
        index = int(rng.integers(0, n_waypoints))
        d = phri.Deformation(window=window, mu=mu, norm=norm, end_rule=end_rule)
        expected = reference_deform(trajectory, index, u_h, window, mu, norm, end_rule)
        case = f"window={window} mu={mu} N={n_waypoints} dof={dof} index={index}"
        out = d.deform(trajectory, index, u_h)
        np.testing.assert_allclose(out, expected, rtol=0, atol=1e-9, err_msg=case)
        assert d.window_at(index, n_waypoints) == reference_window(window, end_rule, index, n_waypoints), case
    np.testing.assert_allclose(d.shape, reference_shape(norm, d.window), rtol=0, atol=1e-9)


@pytest.mark.parametrize("norm", NORMS)
def test_ten_thousand_waypoint_window(norm: str, rng: np.random.Generator) -> None:
    n = 10_000
    d = phri.Deformation(window=n, norm=norm, end_rule="shrink")
    np.testing.assert_allclose(d.shape, closed_form(norm, n), rtol=1e-10)
    trajectory = rng.uniform(-1.0, 1.0, (n + 50, 7))
    u_h = rng.uniform(-5.0, 5.0, 7)
    for index in (0, 49, 1000):  # full window, then shrunk windows near the goal
        out = d.deform(trajectory, index, u_h)
        assert np.isfinite(out).all()
        m = d.window_at(index, len(trajectory))
        assert m == min(n, len(trajectory) - 2 - index)
        delta = (out - trajectory)[index + 1 : index + 1 + m]
        np.testing.assert_allclose(delta, d.mu * np.outer(closed_form(norm, m), u_h), rtol=1e-7, atol=1e-15)


@pytest.mark.parametrize("end_rule", END_RULES)
def test_only_the_window_moves_and_never_the_goal(end_rule: str, rng: np.random.Generator) -> None:
    d = phri.Deformation(window=5, end_rule=end_rule)
    trajectory = rng.uniform(-1.0, 1.0, (12, 7))
    for index in range(12):
        out = d.deform(trajectory, index, np.full(7, 3.0))
        moved = np.flatnonzero((out != trajectory).any(axis=1))
        m = d.window_at(index, 12)
        np.testing.assert_array_equal(moved, np.arange(index + 1, index + 1 + m))
        assert m == 0 or moved[-1] < 11
    # Under "skip" the last full window ends just before the goal.
    assert [d.window_at(i, 12) for i in range(12)] == (
        [5] * 6 + [0] * 6 if end_rule == "skip" else [5] * 6 + [4, 3, 2, 1, 0, 0]
    )


def test_push_direction_and_zero_torque() -> None:
    trajectory = np.zeros((10, 2))
    out = phri.Deformation().deform(trajectory, 0, [2.0, -1.0])
    assert (out[1:6, 0] > 0).all() and (out[1:6, 1] < 0).all()
    np.testing.assert_array_equal(phri.Deformation().deform(trajectory, 0, [0.0, 0.0]), trajectory)
    # The original's sign convention is a negative gain.
    flipped = phri.Deformation(mu=-0.01).deform(trajectory, 0, [2.0, -1.0])
    np.testing.assert_allclose(flipped, -out)


def test_output_contract(rng: np.random.Generator) -> None:
    d = phri.Deformation()
    trajectory = rng.uniform(-1.0, 1.0, (31, 7))
    before = trajectory.copy()
    out = d.deform(trajectory, 3, np.ones(7))
    assert out.shape == (31, 7) and out.dtype == np.float64 and out.flags.c_contiguous and out.flags.writeable
    np.testing.assert_array_equal(trajectory, before)  # the input is not modified
    skipped = d.deform(trajectory, 30, np.ones(7))
    assert skipped is not trajectory and not np.shares_memory(skipped, trajectory)
    np.testing.assert_array_equal(skipped, trajectory)
    # Lists, integer arrays and non-contiguous views are accepted.
    fortran = np.asfortranarray(trajectory)
    np.testing.assert_array_equal(d.deform(fortran, 3, np.ones(7)), out)
    np.testing.assert_array_equal(d.deform(trajectory.tolist(), 3, [1] * 7), out)
    strided = np.repeat(trajectory, 2, axis=0)[::2]
    np.testing.assert_array_equal(d.deform(strided, 3, np.ones(7)), out)
    assert d.deform(np.zeros((8, 3), dtype=np.int64), 0, [1, 2, 3]).dtype == np.float64
    # shape is a copy: changing it changes nothing.
    d.shape[:] = 0.0
    assert d.shape[0] > 1.0


def test_properties_are_read_only() -> None:
    d = phri.Deformation(window=7, mu=0.02, norm="jerk", end_rule="shrink")
    assert (d.window, d.mu, d.norm, d.end_rule) == (7, 0.02, "jerk", "shrink")
    assert d.shape.shape == (7,)
    for name in ("window", "mu", "norm", "end_rule", "shape"):
        with pytest.raises(AttributeError):
            setattr(d, name, 1)
    with pytest.raises(TypeError):
        phri.Deformation(5)  # type: ignore[misc]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"norm": "velocity"}, "norm must be 'acceleration' or 'jerk', got 'velocity'"),
        ({"end_rule": "clamp"}, "end_rule must be 'skip' or 'shrink', got 'clamp'"),
        ({"window": 0}, "window must be in 1..=100000 waypoints, got 0"),
        ({"window": -3}, "window must be in 1..=100000 waypoints, got -3"),
        ({"window": 10**6}, "window must be in 1..=100000 waypoints, got"),
        ({"mu": 0.0}, "mu must be finite and non-zero"),
        ({"mu": float("nan")}, "mu must be finite and non-zero"),
    ],
)
def test_invalid_parameters(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(InvalidParameterError, match=message):
        phri.Deformation(**kwargs)  # type: ignore[arg-type]


def test_argument_errors() -> None:
    d = phri.Deformation()
    trajectory = np.zeros((31, 7))
    with pytest.raises(ShapeError, match=r"trajectory must have shape \(N, dof\), got \(7,\)"):
        d.deform(np.zeros(7), 0, np.ones(7))
    with pytest.raises(ShapeError, match=r"u_h must have shape \(7,\), got \(6,\)"):
        d.deform(trajectory, 0, np.ones(6))
    with pytest.raises(ShapeError, match=r"u_h must have shape \(7,\), got \(1, 7\)"):
        d.deform(trajectory, 0, np.ones((1, 7)))
    bad = trajectory.copy()
    bad[4, 2] = np.nan
    with pytest.raises(NonFiniteError, match=r"trajectory must be finite, got NaN at index \(4, 2\)"):
        d.deform(bad, 0, np.ones(7))
    with pytest.raises(InvalidParameterError, match=r"^u_h is so large that μ·u_h overflows"):
        phri.Deformation(mu=1e308).deform(trajectory, 0, np.full(7, 10.0))
    with pytest.raises(NonFiniteError, match="u_h must be finite"):
        d.deform(trajectory, 0, [1, 1, 1, np.inf, 1, 1, 1])
    with pytest.raises(InvalidParameterError, match="index must be < 31, the number of waypoints, got 31"):
        d.deform(trajectory, 31, np.ones(7))
    with pytest.raises(InvalidParameterError, match="index must be an integer >= 0, got -1"):
        d.deform(trajectory, -1, np.ones(7))
    with pytest.raises(InvalidParameterError, match="index must be < 0"):
        d.deform(np.zeros((0, 7)), 0, np.ones(7))
    with pytest.raises(InvalidParameterError, match="index must be < 10"):
        d.window_at(10, 10)
    with pytest.raises(InvalidParameterError, match="n_waypoints must be an integer >= 0"):
        d.window_at(0, -1)
    # Every argument error is also a ValueError and a PhriError.
    with pytest.raises(ValueError):
        d.deform(trajectory, 0, np.ones(6))
    with pytest.raises(PhriError):
        phri.Deformation(norm="snap")  # type: ignore[arg-type]
