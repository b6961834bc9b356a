"""Arguments across the API (issue 16): sizes bounded by what they cost (#3), no PanicException
(#6), arrays of what is not a real number refused by name (#18), integers out of range an
InvalidParameterError naming the argument rather than a bare OverflowError (#20)."""

from __future__ import annotations

from importlib.resources import files

import numpy as np
import pytest

import phri
from phri.exceptions import ConfigError, InvalidParameterError

HUGE = [-1, -(2**70), 2**64, 2**70]


@pytest.fixture(scope="module")
def features() -> phri.Features:
    return phri.Features(phri.Robot.jaco2(), ["efficiency", "table"])


def _optimizer(features: phri.Features, **kw) -> phri.TrajectoryOptimizer:
    return phri.TrajectoryOptimizer(
        features, kw.pop("waypoints", 11), speed_limits=False, collisions=False, **kw
    )


@pytest.fixture(scope="module")
def levels(features) -> phri.PlanLevels:
    robot = phri.Robot.jaco2()
    q = (robot.lower_limits.clip(-3, 3) + robot.upper_limits.clip(-3, 3)) / 2
    levels, _ = _optimizer(features, waypoints=31).solve_levels([1, 1], q, q + 0.1)
    return levels


@pytest.mark.parametrize("value", HUGE)
@pytest.mark.parametrize(
    "arg, make",
    [
        ("waypoints", lambda f, v: _optimizer(f, waypoints=v)),
        ("max_iterations", lambda f, v: _optimizer(f, max_iterations=v)),
        ("coarsening", lambda f, v: _optimizer(f, coarsening=v)),
        ("coarsest", lambda f, v: _optimizer(f, coarsest=v)),
        (
            "collision_samples",
            lambda f, v: phri.TrajectoryOptimizer(f, 11, speed_limits=False, collision_samples=v),
        ),
        ("window", lambda f, v: phri.Deformation(window=v)),
        ("index", lambda f, v: phri.Deformation().deform(np.zeros((10, 7)), v, np.zeros(7))),
        ("index", lambda f, v: phri.Deformation().window_at(v, 10)),
        ("n_waypoints", lambda f, v: phri.Deformation().window_at(0, v)),
        ("from_waypoints", lambda f, v: f.rescale_weights([1, 1], v, 10)),
        ("to_waypoints", lambda f, v: f.rescale_weights([1, 1], 10, v)),
    ],
)
def test_an_integer_out_of_range_is_an_invalid_parameter_error_naming_it(features, arg, make, value) -> None:
    with pytest.raises(InvalidParameterError, match=rf"^{arg} must be "):
        make(features, value)


@pytest.mark.parametrize("value", [-1, 2, 2**64, 2**80])
def test_plan_levels_level_names_k_and_its_range(levels, value) -> None:
    with pytest.raises(InvalidParameterError, match=rf"^k must be in 0\.\.={len(levels) - 1}"):
        levels.level(value)
    assert levels.level(np.int64(1)).shape == (levels.level(1).shape[0], 7)


def test_keep_out_samples_out_of_range_name_the_feature_item() -> None:
    robot, scene = (
        phri.Robot.jaco2(),
        phri.Scene([phri.SceneObject("laptop", "box", [0.5, 0, 0], size=[0.3, 0.3, 0.02])]),
    )
    for bad in (0, -1, 2**64):
        spec = {"name": "laptop", "keep_out": "laptop", "radius": 0.1, "samples": bad}
        with pytest.raises(InvalidParameterError, match=r"^features\[0\]\.samples must be "):
            phri.Features(robot, [spec], scene=scene)


def test_sizes_are_bounded_by_what_they_cost_and_the_limit_is_stated(features) -> None:
    limit = phri.TrajectoryOptimizer.MAX_WAYPOINTS
    with pytest.raises(InvalidParameterError, match=rf"waypoints must be in 3\.\.={limit} .*got {10**9}"):
        _optimizer(features, waypoints=10**9)
    with pytest.raises(InvalidParameterError, match=rf"waypoints must be in 3\.\.={limit} .*got {2**63}"):
        _optimizer(features, waypoints=2**63)  # was a PanicException
    assert _optimizer(features, waypoints=101).waypoints == 101
    with pytest.raises(
        InvalidParameterError,
        match=rf"max_iterations must be in 1\.\.={phri.TrajectoryOptimizer.MAX_ITERATIONS}",
    ):
        _optimizer(features, max_iterations=10**12)


@pytest.mark.parametrize("max_time", [1e20, 1e300, 86_400.5, 0.0, -1.0, float("nan"), float("inf")])
def test_max_time_is_bounded_and_never_a_panic(features, max_time) -> None:
    with pytest.raises(InvalidParameterError, match=r"^max_time must be in \(0, 86400\] s"):
        _optimizer(features, max_time=max_time)


def test_a_task_file_with_too_many_waypoints_is_a_config_error(tmp_path) -> None:
    source = (files("phri") / "tasks" / "coffee.toml").read_text()
    lines = [line for line in source.splitlines() if not line.startswith("waypoints")]
    path = tmp_path / "many.toml"
    path.write_text("waypoints = 1000000000\n" + "\n".join(lines) + "\n")
    with pytest.raises(
        ConfigError, match=r"key 'waypoints' must be an integer in 3\.\.=10000, got 1000000000"
    ):
        phri.load_task(path)


@pytest.mark.parametrize("value", [True, 1.5, "11", None])
def test_an_integer_argument_of_another_type_is_a_type_error_naming_it(features, value) -> None:
    with pytest.raises(TypeError, match=r"argument 'waypoints'"):
        _optimizer(features, waypoints=value)


NOT_REAL = {
    "complex": np.zeros(7, complex),
    "complex list": [1 + 2j] * 7,
    "masked": np.ma.masked_array(np.zeros(7), mask=[True] + [False] * 6),
    "masked, nothing masked": np.ma.masked_array(np.zeros(7)),
    "bool": np.zeros(7, bool),
    "bool list": [True] * 7,
    "numeric strings": ["1.5"] * 7,
    "string array": np.array(["0"] * 7),
    "bytes": np.array([b"0"] * 7),
    "datetime": np.zeros(7, "datetime64[s]"),
    "timedelta": np.zeros(7, "timedelta64[s]"),
    "structured": np.zeros(7, [("a", float)]),
    "object": np.array([0.0] * 7, dtype=object),
}


@pytest.mark.parametrize("name", list(NOT_REAL))
def test_arrays_that_are_not_real_numbers_are_refused_naming_the_argument(name) -> None:
    robot = phri.Robot.jaco2()
    with pytest.raises(TypeError, match=r"^argument 'q': expected real numbers"):
        robot.gravity(NOT_REAL[name])


def test_real_numbers_in_any_numeric_dtype_and_layout_are_read_as_before() -> None:
    robot = phri.Robot.jaco2()
    rng = np.random.default_rng(0)
    q = rng.uniform(-1, 1, (3, 7))
    expected = robot.gravity(q)
    for variant in (q.tolist(), np.asfortranarray(q), q[::-1][::-1], np.repeat(q, 2, axis=1)[:, ::2]):
        np.testing.assert_allclose(robot.gravity(variant), expected, rtol=0, atol=0)
    np.testing.assert_allclose(robot.gravity(np.zeros(7, np.int32)), robot.gravity(np.zeros(7)), atol=0)
    np.testing.assert_allclose(robot.gravity(np.zeros(7, np.uint8)), robot.gravity(np.zeros(7)), atol=0)


# -- extreme finite values (#19): each parameter's documented range, refused outside it -----------


def test_array_entries_beyond_the_magnitude_limit_are_refused_naming_the_argument(features) -> None:
    robot = phri.Robot.jaco2()
    with pytest.raises(InvalidParameterError, match=r"^q must be within ±1e9, got 1e300 at index 3"):
        robot.gravity([0, 0, 0, 1e300, 0, 0, 0])
    xi = np.zeros((5, 7))
    xi[0, 0] = 1e300  # Φ was inf
    with pytest.raises(InvalidParameterError, match=r"^xi must be within ±1e9, got 1e300 at index \(0, 0\)"):
        features.phi(xi)
    with pytest.raises(InvalidParameterError, match=r"^weights must be within ±1e9"):
        features.weighted_cost(np.zeros((5, 7)), [1e308, 1])


def test_a_negative_efficiency_weight_is_refused_not_converged_at_a_maximum(features) -> None:
    robot = phri.Robot.jaco2()
    q = (robot.lower_limits.clip(-3, 3) + robot.upper_limits.clip(-3, 3)) / 2
    optimizer = _optimizer(features)
    with pytest.raises(InvalidParameterError, match=r"^weights \[0\] \('efficiency'\) must be >= 0, got -1"):
        optimizer.solve([-1, 0], q, q + 0.3)  # reported converged at the straight line, its maximum
    _, info = optimizer.solve([0, 1], q, q + 0.3)  # zero is allowed; other features may be negative
    _, info = optimizer.solve([1, -1], q, q + 0.3)
    assert np.isfinite(info.cost)


@pytest.mark.parametrize("duration", [1e-300, 5e-324, 1e-4, 2e6])
def test_a_duration_that_overflows_the_reference_is_refused(duration) -> None:
    robot = phri.Robot.jaco2()
    q = (robot.lower_limits.clip(-3, 3) + robot.upper_limits.clip(-3, 3)) / 2
    # 1e-300 s gave an acceleration of ±inf.
    with pytest.raises(InvalidParameterError, match=r"^duration must be in \[1e-3, 1e6\] s for 11 waypoints"):
        phri.TimedTrajectory(np.linspace(q, q + 0.5, 11), duration)
    with pytest.raises(InvalidParameterError, match=r"^duration must be in "):
        phri.TrajectoryOptimizer(
            phri.Features(robot, ["efficiency"]), 11, duration=duration, collisions=False
        )
    _, qd, qdd = phri.TimedTrajectory(np.linspace(q, q + 0.5, 11), 1e-3).sample(3e-4)
    assert np.isfinite(qd).all() and np.isfinite(qdd).all()


def test_payload_and_wall_parameters_have_ranges() -> None:
    robot = phri.Robot.jaco2()
    frame = robot.frame_names[-1]
    with pytest.raises(InvalidParameterError, match=r"^com must be within ±10 m"):
        robot.with_payload(frame, 1.0, com=[1e8, 0, 0])
    with pytest.raises(InvalidParameterError, match=r"^com must be within ±1e9"):
        robot.with_payload(frame, 1.0, com=[1e308, 0, 0])
    with pytest.raises(InvalidParameterError, match=r"^mass must be in \[0, 1000\] kg"):
        robot.with_payload(frame, 1e300)
    assert np.isfinite(robot.with_payload(frame, 1000.0, com=[10, -10, 10]).gravity(np.zeros(7))).all()
    for arg, value in [
        ("wall_stiffness", 1e300),
        ("wall_band", 1e12),
        ("wall_damping", 1e6),
        ("wall_margin", 2.0),
    ]:
        with pytest.raises(InvalidParameterError, match=rf"^{arg} must be in \[0, "):
            phri.ImpedanceController(robot, **{arg: value})


def test_collision_spheres_given_by_the_user_are_bounded() -> None:
    robot = phri.Robot.jaco2()
    frame = robot.frame_names[-1]
    many = np.zeros((2000, 3))
    with pytest.raises(InvalidParameterError, match=r"^spheres must hold 1 to 1024 spheres, got 2000"):
        robot.with_collision_spheres("tool", frame, many, np.full(2000, 0.01))
    with pytest.raises(InvalidParameterError, match=r"^spheres radius must be a distance in \(0, 1000\] m"):
        robot.with_collision_spheres("tool", frame, np.zeros((1, 3)), [1e8])
    with pytest.raises(InvalidParameterError, match=r"^spheres centres must be within ±1000 m"):
        robot.with_collision_spheres("tool", frame, [[1e8, 0, 0]], [0.1])
    assert (
        "tool"
        in robot.with_collision_spheres(
            "tool", frame, np.zeros((1024, 3)), np.full(1024, 0.01)
        ).collision_bodies
    )


def test_a_subnormal_speed_limit_is_refused_not_a_nan_reference() -> None:
    """Found by the fuzz suite: switch_to with speed limits of 5e-324 rad/s blended for ever, and
    the reference was NaN from then on."""
    robot = phri.Robot.jaco2()
    q = (robot.lower_limits.clip(-3, 3) + robot.upper_limits.clip(-3, 3)) / 2
    trajectory = phri.TimedTrajectory(np.linspace(q, q + 0.5, 11), 5.0)
    with pytest.raises(
        InvalidParameterError, match=r"^speed_limits \[0\] must be a finite speed >= 1e-6 rad/s, got 5e-324"
    ):
        trajectory.switch_to(np.linspace(q, q + 0.9, 11), 1.0, np.full(7, 5e-324))
    assert np.isfinite(trajectory.switch_to(np.linspace(q, q + 0.9, 11), 1.0, np.full(7, 1e-6)))
    assert all(np.isfinite(a).all() for a in trajectory.sample_many([0.0, 7.0, 23.0]))
