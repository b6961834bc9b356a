"""phri.TimedTrajectory: linear and cubic Hermite interpolation (central-difference tangents, zero end
tangents) against a numpy reference, batch sampling, and typed errors."""

from __future__ import annotations

import re

import numpy as np
import pytest

import phri
from phri import exceptions as ex

TOL = 1e-9


@pytest.fixture
def gen() -> np.random.Generator:
    return np.random.default_rng(31)


def reference_sample(waypoints: np.ndarray, duration: float, t: float, interpolation: str):
    """(q, qd, qdd) at time t, in numpy."""
    w = np.asarray(waypoints, float)
    m = len(w)
    dt = duration / (m - 1)
    if t <= 0.0 or t >= duration:
        q = w[0] if t <= 0.0 else w[-1]
        return q.copy(), np.zeros_like(q), np.zeros_like(q)
    i = min(int(np.floor(t / dt)), m - 2)
    s = t / dt - i
    a, b = w[i], w[i + 1]
    if interpolation == "linear":
        return a + s * (b - a), (b - a) / dt, np.zeros_like(a)
    tangents = np.zeros_like(w)  # dq/ds per segment: central differences, zero at both ends
    tangents[1:-1] = 0.5 * (w[2:] - w[:-2])
    ta, tb = tangents[i], tangents[i + 1]
    h = np.array([2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2])
    dh = np.array([6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s])
    ddh = np.array([12 * s - 6, 6 * s - 4, -12 * s + 6, 6 * s - 2])
    basis = np.stack([a, ta, b, tb])
    return h @ basis, dh @ basis / dt, ddh @ basis / dt**2


def random_waypoints(rng: np.random.Generator, n: int = 31, dof: int = 7) -> np.ndarray:
    return np.cumsum(rng.normal(scale=0.2, size=(n, dof)), axis=0) + rng.uniform(0, 6, dof)


@pytest.mark.parametrize("interpolation", ["linear", "cubic"])
def test_sample_matches_numpy_reference(gen, interpolation):
    for n, dof, duration in [(31, 7, 15.0), (2, 3, 1.0), (5, 1, 0.7)]:
        w = random_waypoints(gen, n, dof)
        traj = phri.TimedTrajectory(w, duration, interpolation)
        times = np.concatenate([gen.uniform(-1.0, duration + 1.0, 300), np.linspace(0, duration, n), [0.0]])
        for t in times:
            for got, want, what in zip(
                traj.sample(t),
                reference_sample(w, duration, t, interpolation),
                "q qd qdd".split(),
                strict=True,
            ):
                np.testing.assert_allclose(
                    got, want, rtol=TOL, atol=TOL, err_msg=f"{interpolation} {what} t={t}"
                )


@pytest.mark.parametrize("interpolation", ["linear", "cubic"])
def test_sample_many_equals_sample(gen, interpolation):
    w = random_waypoints(gen)
    traj = phri.TimedTrajectory(w, 15.0, interpolation)
    times = gen.uniform(-1.0, 16.0, 400)
    q, qd, qdd = traj.sample_many(times)
    assert q.shape == qd.shape == qdd.shape == (400, 7)
    for k, t in enumerate(times):
        one = traj.sample(t)
        for batch, single in zip((q, qd, qdd), one, strict=True):
            np.testing.assert_array_equal(batch[k], single)
    empty = traj.sample_many(np.zeros(0))
    assert all(a.shape == (0, 7) for a in empty)
    q_list, _, _ = traj.sample_many(times.tolist())
    np.testing.assert_array_equal(q_list, q)


@pytest.mark.parametrize("interpolation", ["linear", "cubic"])
def test_waypoints_are_hit_and_the_ends_are_held(gen, interpolation):
    w = random_waypoints(gen)
    traj = phri.TimedTrajectory(w, 15.0, interpolation)
    q, _, _ = traj.sample_many(np.arange(31) * 0.5)
    np.testing.assert_allclose(q, w, rtol=0, atol=1e-12)
    for t, end in [(-3.0, w[0]), (0.0, w[0]), (15.0, w[-1]), (99.0, w[-1])]:
        q, qd, qdd = traj.sample(t)
        np.testing.assert_array_equal(q, end)
        np.testing.assert_array_equal(qd, 0.0)
        np.testing.assert_array_equal(qdd, 0.0)


def test_cubic_is_c1_and_its_derivatives_are_consistent(gen):
    w = random_waypoints(gen)
    traj = phri.TimedTrajectory(w, 15.0)
    assert traj.interpolation == "cubic"
    eps = 1e-9
    for t in np.arange(1, 30) * 0.5:  # velocity continuous across every interior waypoint
        _, before, _ = traj.sample(t - eps)
        _, after, _ = traj.sample(t + eps)
        np.testing.assert_allclose(before, after, atol=1e-6)
    h = 1e-5
    times = gen.uniform(0.01, 14.99, 100)
    q_p, qd_p, _ = traj.sample_many(times + h)
    q_m, qd_m, _ = traj.sample_many(times - h)
    _, qd, qdd = traj.sample_many(times)
    inside = np.floor((times - h) / 0.5) == np.floor((times + h) / 0.5)
    np.testing.assert_allclose(((q_p - q_m) / (2 * h))[inside], qd[inside], atol=1e-6)
    np.testing.assert_allclose(((qd_p - qd_m) / (2 * h))[inside], qdd[inside], atol=1e-4)


def test_properties_index_and_set_waypoints(gen):
    w = random_waypoints(gen)
    traj = phri.TimedTrajectory(w, 15.0, interpolation="linear")
    assert (traj.duration, traj.dt, traj.dof, len(traj), traj.interpolation) == (15.0, 0.5, 7, 31, "linear")
    np.testing.assert_array_equal(traj.waypoints, w)
    copy = traj.waypoints
    copy[:] = 0.0  # a copy: the trajectory is unchanged
    np.testing.assert_array_equal(traj.waypoints, w)
    for t, i in [(-1.0, 0), (0.0, 0), (0.49, 0), (0.5, 1), (7.26, 14), (14.99, 29), (15.0, 30), (40.0, 30)]:
        assert traj.index_at(t) == i, t
    w2 = random_waypoints(gen)
    traj.set_waypoints(w2)
    np.testing.assert_array_equal(traj.waypoints, w2)
    for t in [0.3, 7.7, 14.2]:
        np.testing.assert_allclose(traj.sample(t)[0], reference_sample(w2, 15.0, t, "linear")[0], atol=TOL)
    cubic = phri.TimedTrajectory(w, 15.0, "cubic")
    cubic.set_waypoints(w2.tolist())
    for t in [0.3, 7.7, 14.2]:
        for got, want in zip(cubic.sample(t), reference_sample(w2, 15.0, t, "cubic"), strict=True):
            np.testing.assert_allclose(got, want, rtol=TOL, atol=TOL)


@pytest.mark.parametrize(
    ("args", "error", "pattern"),
    [
        ((np.zeros(7), 15.0), ex.ShapeError, "waypoints must have shape (N, n), got (7,)"),
        ((np.zeros((1, 7)), 15.0), ex.ShapeError, "waypoints must have shape (N, 7) with N >= 2"),
        ((np.zeros((3, 0)), 15.0), ex.ShapeError, "waypoints must have shape (N, 0) with N >= 2"),
        (
            (np.full((3, 7), np.nan), 15.0),
            ex.NonFiniteError,
            "waypoints must be finite, got NaN at index (0, 0)",
        ),
        (
            (np.zeros((3, 7)), 0.0),
            ex.InvalidParameterError,
            "duration must be in [2e-4, 1e6] s for 3 waypoints",
        ),
        ((np.zeros((3, 7)), -2.0), ex.InvalidParameterError, "duration must be in [2e-4, 1e6] s"),
        ((np.zeros((3, 7)), float("nan")), ex.InvalidParameterError, "duration must be in [2e-4, 1e6] s"),
        ((np.zeros((3, 7)), 1e-320), ex.InvalidParameterError, "duration must be in [2e-4, 1e6] s"),
        (
            (np.zeros((3, 7)), 1.0, "quintic"),
            ex.InvalidParameterError,
            "interpolation must be 'cubic' or 'linear', got 'quintic'",
        ),
    ],
)
def test_bad_construction_is_a_typed_error(args, error, pattern):
    with pytest.raises(error, match="^" + re.escape(pattern)):
        phri.TimedTrajectory(*args)


def test_bad_sampling_input_is_a_typed_error(gen):
    traj = phri.TimedTrajectory(random_waypoints(gen), 15.0)
    with pytest.raises(ex.NonFiniteError, match="^t must be finite, got NaN"):
        traj.sample(float("nan"))
    with pytest.raises(ex.NonFiniteError, match="^t must be finite"):
        traj.index_at(float("inf"))
    with pytest.raises(ex.ShapeError, match=re.escape("times must have shape (T,), got (2, 2)")):
        traj.sample_many(np.zeros((2, 2)))
    with pytest.raises(ex.NonFiniteError, match=re.escape("times must be finite, got NaN at index 1")):
        traj.sample_many([0.0, np.nan])
    with pytest.raises(ex.ShapeError, match=re.escape("waypoints must have shape (31, 7), got (30, 7)")):
        traj.set_waypoints(np.zeros((30, 7)))
    with pytest.raises(ex.NonFiniteError, match="^waypoints must be finite"):
        traj.set_waypoints(np.full((31, 7), np.inf))
