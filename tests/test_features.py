"""phri.Features: Φ(ξ) against a plain numpy reference of every feature, gradients against numpy
finite differences, normalisation ranges, and typed errors.

The reference uses phri.Robot.frame_pose only for the forward kinematics of each sample point; the
features themselves (efficiency, table, coffee, laptop/human hinge with 4 sub-samples per segment
(q_{i-1}, q_i], origin) are computed here in numpy, as the authors' published code defines them. The
keep-out features are placed by SCENE as the study's task files place them.
"""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

import phri
from phri import exceptions as ex

LINK_7 = "j2s7s300_link_7"
ALL = ["efficiency", "table", "coffee", "coffee_dot", "laptop", "human", "origin"]
STUDY = ["efficiency", "table", "coffee", "laptop", "human"]
LAPTOP = (-0.7929, -0.1)
HUMAN = (0.0, 0.2)
TOL = 1e-9
#: Objects at the study's places: the keep-out circles are LAPTOP (0.1 m off the laptop) and HUMAN.
SCENE = phri.Scene([
    phri.SceneObject("laptop", "box", [-0.7929, 0.0, -0.0891], size=[0.23, 0.3, 0.025]),
    phri.SceneObject("person", "cylinder", [0.0, 0.2, 0.7484], radius=0.15, length=1.7, kind="person"),
])  # fmt: skip
KEEP_OUT = {
    "laptop": {"name": "laptop", "keep_out": "laptop", "radius": 0.4, "offset": (0.0, -0.1), "samples": 4},
    "human": {"name": "human", "keep_out": "person", "radius": 0.4},
}


def features_of(robot: phri.Robot, names: list[str], **kwargs) -> phri.Features:
    """`names`' features with the keep-out ones placed by SCENE."""
    return phri.Features(robot, [KEEP_OUT.get(n, n) for n in names], scene=SCENE, **kwargs)


POSES = {  # Kinova degrees (the authors' published code)
    "pick_basic": [104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8],
    "pick_shelf": [210.8, 241.0, 209.2, 97.8, 316.8, 91.9, 322.8],
    "place_lower": [210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0],
    "place_higher": [210.5, 118.5, 192.5, 105.4, 229.15, 245.47, 316.4],
}


@pytest.fixture(scope="module")
def jaco2() -> phri.Robot:
    return phri.Robot.jaco2()


@pytest.fixture
def gen() -> np.random.Generator:
    return np.random.default_rng(20170817)


def pose(name: str) -> np.ndarray:
    return np.radians(POSES[name])


def line(a: np.ndarray, b: np.ndarray, n: int = 31, wiggle: float = 0.0) -> np.ndarray:
    """(n, 7) straight joint-space line from a to b, plus an optional smooth wiggle."""
    s = np.linspace(0.0, 1.0, n)[:, None]
    bump = wiggle * np.sin(3.0 * s + np.arange(7)) * s * (1.0 - s)
    return a + s * (b - a) + bump


def random_trajectory(robot: phri.Robot, rng: np.random.Generator, n: int) -> np.ndarray:
    """A random walk of n waypoints from a random configuration within the limits."""
    lo = np.where(np.isfinite(robot.lower_limits), robot.lower_limits, 0.0)
    hi = np.where(np.isfinite(robot.upper_limits), robot.upper_limits, 2.0 * np.pi)
    start = lo + (hi - lo) * (0.1 + 0.8 * rng.random(7))
    return start + np.cumsum(rng.normal(scale=0.15, size=(n, 7)), axis=0)


def reference_per_segment(
    robot: phri.Robot,
    xi: np.ndarray,
    names: list[str],
    *,
    table_height: float = 0.0,
    laptop: tuple[float, float] = LAPTOP,
    human: tuple[float, float] = HUMAN,
    laptop_radius: float = 0.4,
    human_radius: float = 0.4,
    samples: int = 4,
) -> np.ndarray:
    """(N−1, K) features of each segment (q_{i-1}, q_i], in numpy."""
    xi = np.asarray(xi, dtype=float)
    segments = xi[1:] - xi[:-1]
    end = robot.frame_pose(LINK_7, xi[1:])  # pose at q_i, (N−1, 4, 4)
    s = np.arange(1, samples + 1) / samples
    points = xi[:-1, None, :] + s[None, :, None] * segments[:, None, :]  # (N−1, S, n)
    p_xy = robot.frame_pose(LINK_7, points.reshape(-1, 7))[:, :2, 3].reshape(len(segments), samples, 2)

    def hinge(center: tuple[float, float], radius: float) -> np.ndarray:
        return np.maximum(0.0, radius - np.linalg.norm(p_xy - np.asarray(center), axis=-1)).sum(axis=1)

    values = {
        "efficiency": (segments**2).sum(axis=1),
        "table": end[:, 2, 3] - table_height,
        "coffee": np.abs(end[:, 0, 0]) + np.abs(end[:, 1, 0]),
        "coffee_dot": 1.0 - end[:, 2, 0],
        "laptop": hinge(laptop, laptop_radius),
        "human": hinge(human, human_radius),
        "origin": np.linalg.norm(end[:, :3, 3], axis=1),
    }
    return np.stack([values[name] for name in names], axis=1)


def assert_close(actual: np.ndarray, expected: np.ndarray, what: str) -> None:
    err = np.max(np.abs(actual - expected) / np.maximum(1.0, np.abs(expected)))
    assert err < TOL, f"{what}: max relative error {err:.3g}\nactual   {actual}\nexpected {expected}"


# --------------------------------------------------------------------------------------------------
# values


@pytest.mark.parametrize("waypoints", [2, 3, 7, 31])
def test_phi_matches_numpy_reference_on_random_trajectories(jaco2, gen, waypoints):
    features = features_of(jaco2, ALL)
    for _ in range(5):
        xi = random_trajectory(jaco2, gen, waypoints)
        expected = reference_per_segment(jaco2, xi, ALL)
        assert_close(features.per_segment(xi), expected, f"per_segment {xi.tolist()}")
        assert_close(features.phi(xi), expected.sum(axis=0), f"phi {xi.tolist()}")


@pytest.mark.parametrize(
    ("start", "goal", "feature"),
    [("pick_basic", "place_higher", "laptop"), ("pick_shelf", "place_higher", "human")],
)
def test_study_lines_enter_the_keepout_circles(jaco2, start, goal, feature):
    features = features_of(jaco2, ALL)
    xi = line(pose(start), pose(goal))
    phi = features.phi(xi)
    expected = reference_per_segment(jaco2, xi, ALL)
    assert phi[features.index(feature)] > 0.05, f"{start}→{goal} should enter the {feature} circle"
    assert_close(phi, expected.sum(axis=0), f"{start}→{goal}")
    assert_close(features.per_segment(xi), expected, f"{start}→{goal} per segment")


def test_waypoint_zero_counts_only_through_the_first_segment(jaco2):
    features = phri.Features(jaco2, ["table", "coffee", "origin"])
    xi = line(pose("pick_basic"), pose("place_lower"), 6)
    moved = xi.copy()
    moved[0] += 0.3
    np.testing.assert_array_equal(features.phi(xi), features.phi(moved))


def test_scene_parameters_reach_the_features(jaco2, gen):
    scene = dict(
        table_height=-0.1016, laptop=(-0.6, 0.2), human=(-0.3, -0.4), laptop_radius=0.55, human_radius=0.3,
        samples=7,
    )  # fmt: skip
    moved = phri.Scene([
        phri.SceneObject("laptop", "sphere", [-0.5, 0.25, 0.0], radius=0.1),
        phri.SceneObject("person", "cylinder", [-0.3, -0.4, 0.5], radius=0.15, length=1.7, kind="person"),
    ])  # fmt: skip
    features = phri.Features(
        jaco2,
        [
            "efficiency",
            {"name": "table", "height": -0.1016},
            "coffee",
            "coffee_dot",
            {"name": "laptop", "keep_out": "laptop", "radius": 0.55, "offset": [-0.1, -0.05], "samples": 7},
            {"name": "human", "keep_out": "person", "radius": 0.3, "samples": 7},
            {"name": "origin"},
        ],
        scene=moved,
    )
    for xi in [line(pose("pick_basic"), pose("place_higher"), 12), random_trajectory(jaco2, gen, 9)]:
        expected = reference_per_segment(jaco2, xi, ALL, **scene)
        assert_close(features.per_segment(xi), expected, "custom scene")


def test_the_default_frame_is_the_robots_feature_frame(jaco2):
    assert jaco2.feature_frame == LINK_7
    assert jaco2.with_payload(jaco2.cup_frame, 0.3).feature_frame == LINK_7
    assert features_of(jaco2, STUDY).frame == LINK_7
    xi = line(pose("pick_basic"), pose("place_lower"), 5)
    hand = phri.Features(jaco2, ["table"], frame=jaco2.hand_frame)
    np.testing.assert_allclose(hand.phi(xi), jaco2.frame_pose(jaco2.hand_frame, xi[1:])[:, 2, 3].sum())
    bare = phri.Robot.from_urdf_string(jaco2_urdf(), base="root", tip="j2s7s300_end_effector")
    assert bare.feature_frame is None
    with pytest.raises(ex.InvalidParameterError, match="^frame: robot 'j2s7s300' declares no feature frame"):
        phri.Features(bare, ["table"])
    assert phri.Features(bare, ["table"], frame=LINK_7).frame == LINK_7


def test_robot_descriptions_name_their_file_in_errors(tmp_path):
    import importlib.resources

    shipped = importlib.resources.files("phri").joinpath("robots/jaco2")
    (tmp_path / "arm.urdf").write_text(shipped.joinpath("j2s7s300.urdf").read_text())
    (tmp_path / "cup.urdf").write_text(shipped.joinpath("cup.urdf").read_text())  # [carried.cup]
    text = shipped.joinpath("robot.toml").read_text()
    description = tmp_path / "robot.toml"
    description.write_text(text.replace('urdf = "j2s7s300.urdf"', 'urdf = "arm.urdf"'))
    assert phri.Robot.from_description(tmp_path).feature_frame == LINK_7  # a folder holding robot.toml
    assert phri.Robot.from_description(description).feature_frame == LINK_7
    cases = [
        (
            text.replace('urdf = "j2s7s300.urdf"', 'urdf = "missing.urdf"'),
            ex.ConfigError,
            "key 'urdf': cannot read",
        ),
        (text.replace('"j2s7s300_link_7"', '"link_77"'), ex.UnknownNameError, "key 'feature_frame': "),
    ]
    for body, error, message in cases:
        description.write_text(body.replace('urdf = "j2s7s300.urdf"', 'urdf = "arm.urdf"'))
        with pytest.raises(error, match="^" + re.escape(f"{description}: ") + ".*" + re.escape(message)):
            phri.Robot.from_description(description)
    description.write_bytes(b'urdf = "\xff"')
    with pytest.raises(ex.ConfigError, match="not valid TOML"):
        phri.Robot.from_description(description)


def test_a_scene_iterates_and_answers_membership_like_a_mapping():
    scene = phri.load_task("laptop").scene
    assert list(scene) == scene.names == ["table", "laptop", "person"]
    assert "laptop" in scene and "sofa" not in scene and 3 not in scene and None not in scene
    with pytest.raises(
        ex.UnknownNameError, match="unknown scene object 'sofa'; known: table, laptop, person"
    ):
        scene["sofa"]


def jaco2_urdf() -> str:
    import importlib.resources

    return importlib.resources.files("phri").joinpath("robots/jaco2/j2s7s300.urdf").read_text()


def test_names_index_and_input_forms(jaco2):
    features = features_of(jaco2, STUDY)
    assert features.names == STUDY
    assert len(features) == 5
    assert [features.index(n) for n in STUDY] == list(range(5))
    xi = line(pose("pick_basic"), pose("place_lower"), 5)
    expected = features.phi(xi)
    np.testing.assert_array_equal(features.phi(xi.tolist()), expected)
    np.testing.assert_array_equal(features.phi(np.asfortranarray(xi)), expected)
    wide = np.zeros((5, 14))
    wide[:, ::2] = xi
    np.testing.assert_array_equal(features.phi(wide[:, ::2]), expected)
    assert features.phi(xi).dtype == np.float64
    phi, jac = features.phi_gradient(xi)
    assert phi.shape == (5,) and jac.shape == (5, 5, 7)
    cost, grad = features.weighted_cost(xi, np.ones(5))
    assert isinstance(cost, float) and grad.shape == (5, 7)
    assert features.per_segment(xi).shape == (4, 5)


# --------------------------------------------------------------------------------------------------
# gradients


def finite_difference_jacobian(features: phri.Features, xi: np.ndarray, h: float = 1e-6):
    """Central differences (K, N, n) and a mask of entries where a kink lies within ±h."""
    k = len(features)
    fd = np.zeros((k, *xi.shape))
    kink = np.zeros((k, *xi.shape), dtype=bool)
    phi0 = features.phi(xi)
    for idx in np.ndindex(*xi.shape):
        x = xi.copy()
        x[idx] += h
        plus = features.phi(x)
        x[idx] -= 2 * h
        minus = features.phi(x)
        fd[(slice(None), *idx)] = (plus - minus) / (2 * h)
        kink[(slice(None), *idx)] = np.abs((plus - phi0) / h - (phi0 - minus) / h) > 1e-3
    return fd, kink


@pytest.mark.parametrize(
    "trajectory",
    ["random", "pick_basic→place_higher", "pick_shelf→place_higher"],
)
def test_gradient_matches_finite_differences(jaco2, gen, trajectory):
    features = features_of(jaco2, ALL)
    if trajectory == "random":
        xi = random_trajectory(jaco2, gen, 6)
    else:
        start, goal = trajectory.split("→")
        xi = line(pose(start), pose(goal), 8, wiggle=0.3)
    phi, jac = features.phi_gradient(xi)
    assert_close(phi, features.phi(xi), "phi of phi_gradient")
    fd, kink = finite_difference_jacobian(features, xi)
    assert kink.sum() * 20 < kink.size, f"{kink.sum()} kinks of {kink.size}"
    err = np.where(kink, 0.0, np.abs(fd - jac))
    worst = np.unravel_index(np.argmax(err), err.shape)
    assert err.max() < 1e-5, f"{ALL[worst[0]]} d/dxi{worst[1:]}: fd {fd[worst]} vs analytic {jac[worst]}"
    if trajectory != "random":
        hinge = features.index("laptop" if "basic" in trajectory else "human")
        assert np.abs(jac[hinge]).max() > 1e-3, "the keep-out gradient should be active"
    # Waypoint 0 only enters through the first segment's samples.
    for name in ["table", "coffee", "coffee_dot", "origin"]:
        np.testing.assert_array_equal(jac[features.index(name), 0], 0.0)


def test_weighted_cost_is_the_weighted_sum(jaco2, gen):
    features = features_of(jaco2, ALL)
    xi = line(pose("pick_basic"), pose("place_higher"), 9, wiggle=0.2)
    weights = gen.uniform(-2.0, 5.0, len(ALL))
    weights[2] = 0.0  # a zero weight is skipped, not an error
    phi, jac = features.phi_gradient(xi)
    cost, grad = features.weighted_cost(xi, weights)
    assert abs(cost - weights @ phi) < TOL * max(1.0, abs(cost))
    assert_close(grad, np.einsum("k,kij->ij", weights, jac), "weighted gradient")


def test_normalisation_ranges_divide_values_and_gradients(jaco2):
    raw = features_of(jaco2, STUDY)
    ranges = np.array([1.0, 0.6919, 1.8761, 1.0048, 2.5])
    normalised = features_of(jaco2, STUDY, ranges=ranges)
    np.testing.assert_array_equal(raw.ranges, np.ones(5))
    np.testing.assert_allclose(normalised.ranges, ranges, rtol=1e-15)
    xi = line(pose("pick_basic"), pose("place_higher"), 10, wiggle=0.2)
    assert_close(normalised.phi(xi), raw.phi(xi) / ranges, "normalised phi")
    assert_close(normalised.per_segment(xi), raw.per_segment(xi) / ranges, "normalised per segment")
    (_, jac_raw), (_, jac) = raw.phi_gradient(xi), normalised.phi_gradient(xi)
    assert_close(jac, jac_raw / ranges[:, None, None], "normalised gradient")
    w = np.arange(1.0, 6.0)
    assert abs(normalised.weighted_cost(xi, w)[0] - raw.weighted_cost(xi, w / ranges)[0]) < 1e-9


# --------------------------------------------------------------------------------------------------
# errors


def test_unknown_and_repeated_names_are_typed_errors(jaco2):
    with pytest.raises(ex.UnknownNameError, match=r"features.*'tabel'.*efficiency, table"):
        phri.Features(jaco2, ["efficiency", "tabel"])
    with pytest.raises(ex.UnknownNameError, match="link_99"):
        phri.Features(jaco2, ["table"], frame="link_99")
    with pytest.raises(ex.InvalidParameterError, match=r"features.*'table' twice"):
        phri.Features(jaco2, ["table", "table"])
    with pytest.raises(ex.InvalidParameterError, match="features"):
        phri.Features(jaco2, [])
    with pytest.raises(ex.UnknownNameError, match=r"feature.*'laptop'.*known: table"):
        phri.Features(jaco2, ["table"]).index("laptop")


@pytest.mark.parametrize(
    ("laptop", "arg"),
    [
        ({"radius": -0.4}, "features[1].radius"),
        ({"radius": float("nan")}, "features[1].radius"),
        ({"samples": 0}, "features[1].samples"),
        ({"samples": -3}, "features[1].samples"),
        ({"samples": 10**6}, "features[1].samples"),
        ({"keep_out": "lamp"}, "features[1].keep_out"),
        ({"radious": 0.4}, "features[1].radious"),
    ],
)
def test_bad_feature_parameters_name_the_feature_and_parameter(jaco2, laptop, arg):
    spec = {**KEEP_OUT["laptop"], **laptop}
    error = ex.UnknownNameError if "keep_out" in laptop else ex.InvalidParameterError
    with pytest.raises(error, match=rf"^{re.escape(arg)}\b"):
        phri.Features(jaco2, ["table", spec], scene=SCENE)


@pytest.mark.parametrize("ranges", [[1.0, 1e-320], [1.0, 0.0], [1.0, -2.0]])
def test_bad_ranges_raise_invalid_parameter(jaco2, ranges):
    with pytest.raises(ex.InvalidParameterError, match=r"^ranges\b"):
        features_of(jaco2, ["table", "laptop"], ranges=ranges)


def test_keep_out_features_need_a_scene_and_their_parameters(jaco2):
    with pytest.raises(ex.InvalidParameterError, match=r"^scene is needed by keep-out feature 'laptop'"):
        phri.Features(jaco2, ["table", KEEP_OUT["laptop"]])
    with pytest.raises(
        ex.InvalidParameterError, match=r"^features\[0\] is keep-out feature 'human': it needs keep_out"
    ):
        phri.Features(jaco2, ["human"], scene=SCENE)
    with pytest.raises(ex.InvalidParameterError, match=r"^features\[0\].radius: feature 'human' needs"):
        phri.Features(jaco2, [{"name": "human", "keep_out": "person"}], scene=SCENE)
    with pytest.raises(ex.InvalidParameterError, match=r"^features\[0\].height: feature 'coffee' takes no"):
        phri.Features(jaco2, [{"name": "coffee", "height": 0.0}])
    with pytest.raises(ex.InvalidParameterError, match=r"^features\[0\] needs a \"name\""):
        phri.Features(jaco2, [{"radius": 0.4}])
    with pytest.raises(TypeError, match=r"features\[0\] must be a feature name or a mapping"):
        phri.Features(jaco2, [3])


def test_bad_scene_values_and_range_shapes(jaco2):
    with pytest.raises(ex.NonFiniteError, match=r"^features\[0\].offset"):
        phri.Features(jaco2, [{**KEEP_OUT["laptop"], "offset": (float("nan"), 0.0)}], scene=SCENE)
    with pytest.raises(ex.NonFiniteError, match=r"^features\[0\].height"):
        phri.Features(jaco2, [{"name": "table", "height": float("inf")}])
    with pytest.raises(ex.ShapeError, match=re.escape("ranges must have shape (2,), got (3,)")):
        features_of(jaco2, ["table", "laptop"], ranges=[1.0, 1.0, 1.0])
    with pytest.raises(ex.NonFiniteError, match="^ranges"):
        features_of(jaco2, ["table", "laptop"], ranges=[1.0, float("nan")])


@pytest.mark.parametrize(
    ("xi", "error", "message"),
    [
        (np.zeros(7), ex.ShapeError, "xi must have shape (N, 7), got (7,)"),
        (np.zeros((5, 6)), ex.ShapeError, "xi must have shape (N, 7), got (5, 6)"),
        (np.zeros((1, 7)), ex.ShapeError, "xi must have shape (N, 7) with N >= 2, got (1, 7)"),
        (np.zeros((2, 7, 1)), ex.ShapeError, "xi must have shape (N, 7), got (2, 7, 1)"),
        (np.full((3, 7), np.nan), ex.NonFiniteError, "xi must be finite, got NaN at index (0, 0)"),
    ],
)
def test_bad_trajectories_are_typed_errors(jaco2, xi, error, message):
    features = features_of(jaco2, STUDY)
    for method in [features.phi, features.phi_gradient, features.per_segment]:
        with pytest.raises(error, match=re.escape(message)):
            method(xi)
    with pytest.raises(error, match=re.escape(message)):
        features.weighted_cost(xi, np.ones(5))


def test_bad_weights_are_typed_errors(jaco2):
    features = features_of(jaco2, STUDY)
    xi = line(pose("pick_basic"), pose("place_lower"), 4)
    with pytest.raises(ex.ShapeError, match=re.escape("weights must have shape (5,), got (4,)")):
        features.weighted_cost(xi, np.ones(4))
    with pytest.raises(ex.NonFiniteError, match="^weights must be finite"):
        features.weighted_cost(xi, [1.0, 1.0, np.inf, 1.0, 1.0])
    with pytest.raises(TypeError):
        phri.Features(jaco2, "table")  # a string is not a list of names


def test_keep_out_circles_are_placed_by_their_scene_object(jaco2):
    task = phri.load_task("laptop")
    laptop = task.scene["laptop"]
    moved = phri.Scene(
        [
            phri.SceneObject("laptop", "box", laptop.position + [0.25, 0.0, 0.0], size=laptop.size),
        ]
    )
    spec = {"name": "laptop", "keep_out": "laptop", "radius": 0.4, "offset": (0.0, -0.1)}
    assert phri.Features(jaco2, ["efficiency", spec], scene=moved).keep_out_circles == {
        "laptop": ((-0.7929 + 0.25, -0.1), 0.4)
    }
    assert phri.Features(jaco2, ["efficiency", "table"]).keep_out_circles == {}
    assert task.keep_out_circle("laptop") == ((-0.7929, -0.1), 0.4)


def test_phi_and_its_gradient_stream_in_constant_memory_per_waypoint() -> None:
    """Issue 16 #4: Φ and ∂Φ/∂ξ kept every waypoint's kinematics (about 3.7 kB each, an abort at
    10⁷ waypoints). Now the peak memory of a call is its input and output only."""
    script = """
import resource, numpy as np, phri
robot = phri.Robot.jaco2()
features = phri.Features(robot, ["efficiency", "table", "coffee"])
xi = np.random.default_rng(0).uniform(-1, 1, (200_000, 7))
features.phi(xi[:10]), features.phi_gradient(xi[:10])  # warm up the allocator and the workspace
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
phi = features.phi(xi)
grown_phi = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
_, jac = features.phi_gradient(xi)
grown_grad = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
assert np.isfinite(phi).all() and jac.shape == (3, 200_000, 7)
print(grown_phi, grown_grad, jac.nbytes // 1024)
"""
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=True
    )
    grown_phi, grown_grad, jac_kb = (int(v) for v in out.stdout.split())
    # The old workspace alone took 3.7 kB × 200,000 = 740 MB.
    assert grown_phi < 20_000, f"phi grew the peak by {grown_phi} kB"
    assert grown_grad < jac_kb + 20_000, (
        f"phi_gradient grew the peak by {grown_grad} kB for a {jac_kb} kB result"
    )
