"""Task files: the shipped study tasks and errors that name the file, the key and the expectation."""

from __future__ import annotations

import importlib.resources
import math
import pickle
import re
import sys

import numpy as np
import pytest

import phri
from phri.exceptions import ConfigError, UnknownNameError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


def test_the_four_study_tasks_ship_with_their_numbers() -> None:
    assert phri.task_names() == [
        "coffee",
        "fr3_coffee",
        "fr3_human",
        "fr3_laptop",
        "fr3_table",
        "human",
        "laptop",
        "table",
    ]
    table = phri.load_task("table")
    assert table.feature_names == ["efficiency", "table"]
    np.testing.assert_allclose(np.rad2deg(table.start), [104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8])
    np.testing.assert_allclose(table.vector("true"), [1.0, 1.0])
    np.testing.assert_allclose(table.vector("step"), [0.0, 2.0])
    laptop = phri.load_task("laptop")
    assert (laptop.vector("upper")[1], laptop.vector("step")[1], laptop.vector("true")[1]) == (
        10.0,
        100.0,
        10.0,
    )
    assert laptop.features[0].learned is False and laptop.features[1].learned is True
    assert phri.load_task("human").duration == 15.0 and phri.load_task("coffee").waypoints == 31


def test_a_user_task_file_loads_the_same_way(tmp_path) -> None:
    text = phri.load_task("coffee").source
    src = tmp_path / "mine.toml"
    shipped = __import__("importlib.resources").resources.files("phri").joinpath("tasks", "coffee.toml")
    src.write_text(shipped.read_text().replace('name = "coffee"', 'name = "mine"'))
    task = phri.load_task(src)
    assert task.name == "mine" and task.source == str(src) and text.endswith("coffee.toml")


BROKEN = [
    ("start = [1, 2", "not valid TOML"),
    ('name = "x"\ntask_feature = "table"\nstart = [0,0,0,0,0,0,0]\n', "missing key 'goal'"),
]


@pytest.mark.parametrize(("body", "message"), BROKEN)
def test_broken_files_name_the_file_and_the_problem(tmp_path, body, message) -> None:
    path = tmp_path / "broken.toml"
    path.write_text(body)
    with pytest.raises(ConfigError, match=message) as e:
        phri.load_task(path)
    assert str(path) in str(e.value)


def _variant(tmp_path, old: str, new: str):
    shipped = __import__("importlib.resources").resources.files("phri").joinpath("tasks", "table.toml")
    path = tmp_path / "variant.toml"
    text = shipped.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    return path


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "start = [104.2, 151.6",
            "start = [104.2, 151.6, 1.0",
            r"key 'start' must be a list of 7 finite numbers",
        ),
        ("duration = 15.0", "duration = -1.0", r"key 'duration' must be a number > 0"),
        ("waypoints = 31", "waypoints = 2", r"key 'waypoints' must be an integer in 3..=10000"),
        ("knots = 4 ", "knots = 2 ", r"key 'knots' must be 0 \(plan every waypoint\) or"),
        ("knots = 4 ", "knots = 31 ", r"key 'knots' must be .* \(3, 4, 6, 7, 11, 16\)"),
        ("knots = 4 ", "knots = 5 ", r"key 'knots' must be .*every knot on one of the 31 waypoints"),
        ("knots = 4 ", "knots = 4.5 ", r"key 'knots' must be"),
        ("[features.table]", "[features.tabel]", r"key 'features.tabel': unknown feature"),
        ("step = 2.0", "step = -2.0", r"key 'features.table.step' must be a number >= 0"),
        ("upper = 1.0", "upper = -1.0", r"key 'features.table.lower' must be <= upper"),
        ('task_feature = "table"', 'task_feature = "laptop"', r"key 'task_feature' must be one of"),
        ('angles = "degrees"', 'angles = "gradians"', r"key 'angles' must be 'degrees' or 'radians'"),
    ],
)
def test_bad_values_name_the_key_and_the_expectation(tmp_path, old, new, message) -> None:
    with pytest.raises(ConfigError, match=message):
        phri.load_task(_variant(tmp_path, old, new))


def test_unknown_task_names_list_the_known_ones() -> None:
    with pytest.raises(
        UnknownNameError,
        match="known: coffee, fr3_coffee, fr3_human, fr3_laptop, fr3_table, human, laptop, table",
    ):
        phri.load_task("kitchen")
    with pytest.raises(ConfigError, match="not found"):
        phri.load_task("/does/not/exist.toml")


def test_degrees_become_radians() -> None:
    task = phri.load_task("human")
    assert math.isclose(task.start[0], math.radians(210.8))


def _shipped_text(name: str) -> str:
    return importlib.resources.files("phri").joinpath("tasks", f"{name}.toml").read_text()


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "step = 2.0",
            "stpe = 2.0",
            "unknown key 'features.table.stpe' in table [features.table]; "
            "allowed keys: initial, true, step, lower, upper, learned, height; did you mean 'step'?",
        ),
        (
            "duration = 15.0",
            "duraton = 15.0",
            "unknown key 'duraton' in the top-level table; allowed keys: name, title, angles, start, goal, "
            "duration, waypoints, knots, task_feature, feature_frame, features, unmodelled, scene, robot, "
            "safety; "
            "did you mean 'duration'?",
        ),
        (
            "radius = 0.15",
            "raduis = 0.15",
            "unknown key 'scene.person.raduis' in table [scene.person]; allowed keys: shape, size, radius, "
            "length, position, rpy, margin, kind; did you mean 'radius'?",
        ),
        (
            "[features.table]",
            "[features.tabel]",
            "key 'features.tabel': unknown feature; known: efficiency, table, coffee, coffee_dot, laptop, "
            "human, origin; did you mean 'table'?",
        ),
        ("true = 1.0\nstep", "tru = 1.0\nstep", "unknown key 'features.table.tru'"),  # not "missing 'true'"
    ],
)
def test_unknown_keys_name_the_table_the_allowed_keys_and_the_closest(tmp_path, old, new, message) -> None:
    path = _variant(tmp_path, old, new)
    with pytest.raises(ConfigError, match=re.escape(message)) as e:
        phri.load_task(path)
    assert str(e.value).startswith(f"{path}: ")


def test_an_unknown_key_with_no_close_match_lists_the_allowed_keys_only(tmp_path) -> None:
    message = r"unknown key 'colour' in the top-level table; allowed keys: "
    with pytest.raises(ConfigError, match=message) as e:
        phri.load_task(_variant(tmp_path, "waypoints = 31", "waypoints = 31\ncolour = 3"))
    assert "did you mean" not in str(e.value)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("duration = 15.0", "duration = inf", "key 'duration' must be a finite number, got inf"),
        ("duration = 15.0", "duration = nan", "key 'duration' must be a finite number, got nan"),
        ("true = 1.0\nstep", "true = inf\nstep", "key 'features.table.true' must be a finite number"),
        ("step = 2.0", "step = inf", "key 'features.table.step' must be a finite number, got inf"),
        (
            "upper = 1.0",
            "upper = inf",
            "key 'features.table.upper' must be a finite number (leave it out for no upper bound), got inf",
        ),
        ("lower = 0.0", "lower = -inf", "key 'features.table.lower' must be a finite number, got -inf"),
        ("[-0.405, 0.0, -0.4516]", "[-0.405, 0.0, -inf]", "key 'scene.table.position' must be a list of 3"),
        ("radius = 0.15", "radius = inf", "key 'scene.person.radius' must be a finite number, got inf"),
        ("duration = 15.0", "duration = 1" + "0" * 400, "key 'duration' must be a finite number"),
        ("start = [104.2,", "start = [1" + "0" * 400 + ",", "key 'start' must be a list of 7 finite numbers"),
        (
            "[0.23, 0.3, 0.025]",
            "[0.23, inf, 0.025]",
            "key 'scene.laptop.size' must be a list of 3 finite numbers",
        ),
    ],
)
def test_numbers_must_be_finite(tmp_path, old, new, message) -> None:
    path = _variant(tmp_path, old, new)
    with pytest.raises(ConfigError, match=re.escape(message)) as e:
        phri.load_task(path)
    assert str(e.value).startswith(f"{path}: ")


def test_leaving_upper_out_still_means_no_upper_bound(tmp_path) -> None:
    task = phri.load_task(_variant(tmp_path, "upper = 1.0\n", ""))
    assert task.features[1].upper == math.inf


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "start = [104.2, 151.6, 183.8, 101.8,",
            "start = [104.2, 40.0, 183.8, 101.8,",
            "key 'start' must be within the joint limits of j2s7s300 in degrees: "
            "start[1] = 40.0 is outside [47.000014, 313.000025] (joint 'j2s7s300_joint_2')",
        ),
        (
            "goal = [210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]",
            "goal = [210.8, 101.6, 192.0, 335, 222.2, 300, 322.0]",
            "key 'goal' must be within the joint limits of j2s7s300 in degrees: "
            "goal[3] = 335 is outside [30.000013, 330.000027] (joint 'j2s7s300_joint_4'); "
            "goal[5] = 300 is outside [64.999999, 294.999983] (joint 'j2s7s300_joint_6')",
        ),
        (
            'angles = "degrees"\n',
            'angles = "radians"\n',  # the same numbers read as radians: joint 2 at 151.6 rad
            "key 'start' must be within the joint limits of j2s7s300 in radians: "
            "start[1] = 151.6 is outside [0.820305, 5.462881] (joint 'j2s7s300_joint_2')",
        ),
    ],
)
def test_start_and_goal_outside_the_joint_limits_fail_at_load_in_the_files_unit(
    tmp_path, robot, old, new, message
) -> None:
    path = _variant(tmp_path, old, new)
    with pytest.raises(ConfigError, match=re.escape(message)) as e:
        phri.load_task(path)
    assert str(e.value).startswith(f"{path}: ")
    # What the planner would have rejected later, with no file, key or degrees in its message.
    key = message.split("'")[1]
    text = path.read_text()
    values = tomllib.loads(text)[key]
    scale = math.pi / 180 if 'angles = "degrees"' in text else 1.0
    with pytest.raises(ValueError, match="outside the limits"):
        robot.check_limits(np.asarray(values, dtype=float) * scale)


def test_poses_at_the_limits_and_on_continuous_joints_load(tmp_path, robot) -> None:
    lo, hi = robot.lower_limits, robot.upper_limits
    # Radians, exactly at the limits of joints 2, 4 and 6; continuous joints 1, 3, 5, 7 take any angle.
    start = [-720.0, float(lo[1]), 1e6, float(hi[3]), 0.0, float(lo[5]), 360.0]
    goal = [0.0, float(hi[1]), 0.0, float(lo[3]), 0.0, float(hi[5]), 0.0]
    text = _shipped_text("table").replace('angles = "degrees"', 'angles = "radians"')
    lines = [line for line in text.splitlines() if not line.startswith(("start =", "goal ="))]
    path = tmp_path / "limits.toml"
    path.write_text(f"start = {start}\ngoal = {goal}\n" + "\n".join(lines))
    task = phri.load_task(path)
    np.testing.assert_array_equal(task.start, start)
    np.testing.assert_array_equal(task.goal, goal)
    robot.check_limits(task.start)
    robot.check_limits(task.goal)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "true = 1.0\nstep",
            "true = 2.0\nstep",
            "key 'features.table.true' must be within [lower, upper] = [0.0, 1.0] of feature 'table', "
            "got 2.0",
        ),
        (
            "initial = 0.0",
            "initial = 1.5",
            "key 'features.table.initial' must be within [lower, upper] = [0.0, 1.0] of feature 'table', "
            "got 1.5",
        ),
        (
            "initial = 0.0",
            "initial = -0.5",
            "key 'features.table.initial' must be within [lower, upper] = [0.0, 1.0] of feature 'table', "
            "got -0.5",
        ),
        (  # a fixed weight is checked against the bounds the file gives it
            "learned = false",
            "learned = false\nupper = 0.5",
            "key 'features.efficiency.initial' must be within [lower, upper] = [-inf, 0.5] of feature "
            "'efficiency', got 1.0",
        ),
        (  # no bounds given: a learned weight stays in [0, inf)
            "true = 1.0\nstep = 2.0\nlower = 0.0\nupper = 1.0",
            "true = -1.0\nstep = 2.0",
            "key 'features.table.true' must be within [lower, upper] = [0.0, inf] of feature 'table', "
            "got -1.0",
        ),
    ],
)
def test_initial_and_true_weights_must_lie_within_the_bounds(tmp_path, old, new, message) -> None:
    path = _variant(tmp_path, old, new)
    with pytest.raises(ConfigError, match=re.escape(message)) as e:
        phri.load_task(path)
    assert str(e.value).startswith(f"{path}: ")


def test_a_fixed_weight_keeps_its_initial_value_as_its_bounds(tmp_path) -> None:
    # learned = false with no bounds: clip range [initial, initial]; its true weight is not checked.
    task = phri.load_task(_variant(tmp_path, "initial = 1.0\ntrue = 1.0", "initial = 1.0\ntrue = 3.0"))
    efficiency = task.features[0]
    assert (efficiency.learned, efficiency.lower, efficiency.upper, efficiency.true) == (False, 1.0, 1.0, 3.0)
    task = phri.load_task(_variant(tmp_path, "learned = false", "learned = false\nlower = 0.5\nupper = 2.0"))
    assert (task.features[0].lower, task.features[0].upper) == (0.5, 2.0)


def test_a_file_that_is_not_utf8_names_the_file_and_the_line(tmp_path) -> None:
    path = tmp_path / "latin1.toml"
    text = _shipped_text("table").replace('title = "Task 2', 'title = "Tâche 2')
    path.write_bytes(text.encode().replace("Tâche".encode(), "Tâche".encode("latin-1")))
    with pytest.raises(ConfigError, match=r"not UTF-8 text \(line 4, byte \d+: b'\\xe2'\)") as e:
        phri.load_task(path)
    assert str(e.value).startswith(f"{path}: ")


@pytest.mark.parametrize("newline", ["\r\n", "\r"])
def test_windows_and_old_mac_line_endings_still_load(tmp_path, newline) -> None:
    path = tmp_path / "endings.toml"
    path.write_bytes(_shipped_text("table").replace("\n", newline).encode())
    assert phri.load_task(path).duration == 15.0


@pytest.mark.parametrize("name", ["coffee", "human", "laptop", "table"])
def test_shipped_tasks_place_the_study_objects(name) -> None:
    task = phri.load_task(name)
    assert task.scene == phri.load_task("laptop").scene  # one scene for the whole study
    assert task.scene.names == ["table", "laptop", "person"]
    table, laptop, person = task.scene.objects
    assert table.top == pytest.approx(-0.1016, abs=1e-12) and table.shape == "box"
    np.testing.assert_array_equal(laptop.position, [-0.7929, 0.0, -0.0891])
    assert (person.kind, person.shape, person.radius, person.length) == ("person", "cylinder", 0.15, 1.7)
    assert task.feature_frame is None  # the robot's: link_7


def test_the_keep_out_features_are_the_authors_circles() -> None:
    # Centres, radii and samples as in the authors' code: laptop (-0.7929, -0.1), human (0, 0.2), 0.4 m.
    assert phri.load_task("laptop").keep_out_circle("laptop") == ((-0.7929, -0.1), 0.4)
    assert phri.load_task("human").keep_out_circle("human") == (pytest.approx((0.0, 0.2), abs=1e-12), 0.4)
    assert phri.load_task("human").keep_out_circle("laptop") is None
    for name in ("laptop", "human"):
        assert phri.load_task(name).features[1].params["samples"] == 4


def test_tasks_survive_pickling_for_worker_processes() -> None:
    task = phri.load_task("laptop")
    copy = pickle.loads(pickle.dumps(task))
    assert copy.scene == task.scene and copy.features == task.features
    assert copy.scene["person"].kind == "person"


def test_scene_values_are_read_from_the_file(tmp_path, robot) -> None:
    text = _shipped_text("human")
    path = tmp_path / "moved.toml"
    path.write_text(text.replace("position = [-0.2, 1.0, 0.7484]", "position = [0.1, 0.5, 0.7484]")
                    .replace("radius = 0.4 ", "radius = 0.3 "))  # fmt: skip
    task = phri.load_task(path)
    np.testing.assert_array_equal(task.scene["person"].position, [0.1, 0.5, 0.7484])
    assert task.keep_out_circle("human") == (
        pytest.approx((0.3, -0.3)),
        0.3,
    )  # the torso moved, the offset kept
    xi = np.linspace(task.start, task.goal, task.waypoints)
    assert not np.array_equal(
        task.feature_set(robot).phi(xi), phri.load_task("human").feature_set(robot).phi(xi)
    )


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            'keep_out = "person"',
            'keep_out = "persn"',
            "key 'features.human.keep_out' must be the name of an object of the task's [scene] "
            "(table, laptop, person), got 'persn'",
        ),
        (
            'keep_out = "person"     # the scene object the cup is kept away from\n',
            "",
            "missing key 'features.human.keep_out'",
        ),
        ("samples = 4 ", "samples = 0 ", "key 'features.human.samples' must be an integer >= 1, got 0"),
        ("samples = 4 ", "samples = 5000 ", "features[1].samples must be in 1..=1000 points per segment"),
        ("radius = 0.4 ", "radius = -0.4 ", "key 'features.human.radius' must be a number > 0, got -0.4"),
        (
            "radius = 0.4 ",
            "raduis = 0.4 ",
            "unknown key 'features.human.raduis' in table [features.human]; allowed keys: initial, true, "
            "step, "
            "lower, upper, learned, keep_out, radius, offset, samples; did you mean 'radius'?",
        ),
        (
            'shape = "cylinder"',
            'shape = "cylindre"',
            "key 'scene.person.shape' must be one of the shapes: plane, box, cylinder, sphere, "
            "got 'cylindre'; "
            "did you mean 'cylinder'?",
        ),
        ("length = 1.7\n", "", "key 'scene.person': length: a cylinder needs its length [m]"),
        ('kind = "person"', 'kind = "human"', "key 'scene.person.kind' must be one of: furniture, person"),
        (
            "length = 1.7",
            "length = 1.7\nmargin = -0.1",
            "key 'scene.person': margin must be a finite distance >= 0 m, got -0.1",
        ),
        (
            'task_feature = "human"',
            'task_feature = "human"\nfeature_frame = "link_77"',
            "key 'feature_frame' must be a frame of j2s7s300",
        ),
        ("[scene.laptop]", "[scene.person]", "not valid TOML"),  # a name twice
        ('keep_out = "person"', "keep_out = 3", "key 'features.human.keep_out' must be a string, got 3"),
        (
            "position = [-0.2, 1.0, 0.7484]",
            "position = [0.0, 0.2]",
            "key 'scene.person.position' must be a list of 3 finite numbers, got [0.0, 0.2]",
        ),
        (
            'task_feature = "human"',
            'task_feature = "human"\nfeature_frame = "j2s7s300_link7"',
            "key 'feature_frame' must be a frame of j2s7s300, got 'j2s7s300_link7'; "
            "did you mean 'j2s7s300_link_7'?",
        ),
    ],
)
def test_bad_scene_and_feature_parameters_name_the_file_and_key(tmp_path, old, new, message) -> None:
    text = _shipped_text("human")
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError, match=re.escape(message)) as e:
        phri.load_task(path)
    assert str(e.value).startswith(f"{path}: ")


def test_a_task_may_name_its_feature_frame(tmp_path, robot) -> None:
    text = _shipped_text("human").replace(
        'task_feature = "human"', 'task_feature = "human"\nfeature_frame = "j2s7s300_end_effector"'
    )
    path = tmp_path / "frame.toml"
    path.write_text(text)
    task = phri.load_task(path)
    assert task.feature_frame == "j2s7s300_end_effector"
    assert task.feature_set(robot).frame == "j2s7s300_end_effector"


def test_a_scene_that_is_not_a_table_is_an_error(tmp_path) -> None:
    text = _shipped_text("table")
    path = tmp_path / "scene.toml"
    path.write_text("scene = 3\n" + text[: text.index("# Where the objects are")])
    message = f"{path}: key 'scene' must be a table of object tables, e.g. [scene.table], got 3"
    with pytest.raises(ConfigError, match=re.escape(message)):
        phri.load_task(path)


@pytest.mark.parametrize("name", ["../x", "a/b", "nul\\u0000", "line\\nbreak", ".hidden", "x" * 300, ""])
def test_task_names_that_cannot_name_files_are_refused(tmp_path, name) -> None:
    """Issue 16 #9: the task's name goes into file names."""
    with pytest.raises(ConfigError, match=r"variant.toml: name must be 1-64 letters, digits and _ - \."):
        phri.load_task(_variant(tmp_path, 'name = "table"', f'name = "{name}"'))


def test_unicode_task_names_are_accepted(tmp_path) -> None:
    assert phri.load_task(_variant(tmp_path, 'name = "table"', 'name = "café-2"')).name == "café-2"


def test_hostile_task_files_are_config_errors(tmp_path) -> None:
    """Issue 16 #9: huge integers, deep nesting, a byte-order mark, a folder, a FIFO and a symbolic
    link loop each get a ConfigError saying what is wrong."""
    import os

    shipped = importlib.resources.files("phri").joinpath("tasks", "table.toml").read_text()
    cases = {
        "digits.toml": ("x = " + "9" * 5000 + "\n", "not a task file phri can read"),
        "nested.toml": ("x = " + "[" * 100_000 + "]" * 100_000 + "\n", "not"),
    }
    for name, (text, message) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ConfigError, match=message):
            phri.load_task(tmp_path / name)
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + shipped.encode())
    assert phri.load_task(bom).name == "table"
    (tmp_path / "folder.toml").mkdir()
    with pytest.raises(ConfigError, match="is a folder, not a task file"):
        phri.load_task(tmp_path / "folder.toml")
    os.mkfifo(tmp_path / "fifo.toml")
    with pytest.raises(ConfigError, match="is not a regular file"):
        phri.load_task(tmp_path / "fifo.toml")
    (tmp_path / "loop.toml").symlink_to(tmp_path / "loop.toml")
    with pytest.raises(ConfigError, match="cannot be read as a task file"):
        phri.load_task(tmp_path / "loop.toml")
