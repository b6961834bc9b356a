"""Features a lab defines itself: declared kinds against a numpy reference and finite differences on
every frame of the JACO2 and the FR3; a Python re-implementation of the table feature against the
built-in (Φ, the plan's cost, what the learner learns from a push); a Python feature without a
gradient; bad Python features (wrong shape, NaN, raises, slow) as typed errors naming the feature,
also in a solve and on the learner's worker thread (the replan is rejected, the arm keeps its plan);
task files that declare features or name Python code; a study of a task with a Python feature that
runs, resumes and reports, its simulated people correcting it."""

from __future__ import annotations

import csv
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import phri
from phri import exceptions as ex
from phri.cli import main as phri_main

TICK = 0.001  # s


def random_trajectory(robot: phri.Robot, rng: np.random.Generator, waypoints: int) -> np.ndarray:
    lower, upper = robot.lower_limits, robot.upper_limits
    lo, hi = np.maximum(lower, -2 * np.pi), np.minimum(upper, 2 * np.pi)
    a, b = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), (2, robot.nq))
    s = np.linspace(0.0, 1.0, waypoints)[:, None]
    wiggle = 0.2 * np.sin(3 * s + np.arange(robot.nq)) * s * (1 - s)
    return np.clip(a + s * (b - a) + wiggle, lo, hi)


def fd_gradient(features: phri.Features, xi: np.ndarray, h: float = 1e-6) -> np.ndarray:
    out = np.zeros((len(features), *xi.shape))
    for idx in np.ndindex(*xi.shape):
        up, down = xi.copy(), xi.copy()
        up[idx] += h
        down[idx] -= h
        out[(slice(None), *idx)] = (features.phi(up) - features.phi(down)) / (2 * h)
    return out


def reference_per_segment(
    robot: phri.Robot, frame: str, scene: phri.Scene, xi: np.ndarray, specs
) -> np.ndarray:
    """φ per segment of the declared specs, from Robot.frame_pose and numpy alone."""
    pose = robot.frame_pose(frame, xi)  # (N, 4, 4)
    p, rot = pose[:, :3, 3], pose[:, :3, :3]
    cols = []
    for spec in specs:
        kind = spec["kind"]
        if kind == "height":
            cols.append(p[1:, 2] - (scene["table"].top + spec.get("offset", 0.0)))
        elif kind == "distance":
            c = np.asarray(scene[spec["object"]].position) + np.asarray(spec.get("offset", (0.0, 0.0, 0.0)))
            k = spec["samples"]
            s = np.arange(1, k + 1) / k
            q = xi[:-1, None, :] + s[None, :, None] * (xi[1:, None, :] - xi[:-1, None, :])
            ps = robot.frame_pose(frame, q.reshape(-1, robot.nq))[:, :3, 3].reshape(-1, k, 3)
            d = ps - c
            if spec.get("shape", "cylinder") == "cylinder":
                d = d[..., :2]
            cols.append(np.maximum(0.0, spec["radius"] - np.linalg.norm(d, axis=-1)).sum(axis=1))
        elif kind == "alignment":
            axis = "xyz".index(spec["axis"])
            d = np.asarray(spec["direction"]) / np.linalg.norm(spec["direction"])
            cols.append(1.0 - rot[1:, :, axis] @ d)
        elif kind == "joint_distance":
            cols.append(np.sum((xi[1:] - np.asarray(spec["pose"])) ** 2, axis=1))
        elif kind == "speed":
            cols.append(np.sum((p[1:] - p[:-1]) ** 2, axis=1))
    return np.stack(cols, axis=1)


def declared_specs(robot: phri.Robot, frame: str, scene: phri.Scene) -> list[dict]:
    target = "laptop" if "laptop" in scene else "table"
    laptop = np.asarray(scene[target].position)
    return [
        {"name": "height", "kind": "height", "frame": frame, "object": "table", "offset": 0.05},
        # A circle and a ball big enough to be entered by the random paths' frames.
        {"name": "near", "kind": "distance", "frame": frame, "object": target, "radius": 1.2,
         "offset": (0.1, -0.2, 0.0), "samples": 3},
        {"name": "ball", "kind": "distance", "frame": frame, "object": target, "radius": 1.0 + abs(laptop[2]),
         "shape": "sphere", "samples": 2},
        {"name": "level", "kind": "alignment", "frame": frame, "axis": "y", "direction": (0.2, -0.3, 1.0)},
        {"name": "pose", "kind": "joint_distance", "pose": tuple(np.linspace(0.5, 1.5, robot.nq))},
        {"name": "speed", "kind": "speed", "frame": frame},
    ]  # fmt: skip


ROBOT_SCENES = {"jaco2": "table", "fr3": "fr3_table"}


@pytest.mark.parametrize("robot_name", list(ROBOT_SCENES))
def test_declared_kinds_match_numpy_and_finite_differences_on_every_frame(robot_name):
    robot = getattr(phri.Robot, robot_name)()
    scene = phri.load_task(ROBOT_SCENES[robot_name]).scene
    rng = np.random.default_rng(7)
    checked = 0
    for frame in robot.frame_names:
        specs = declared_specs(robot, frame, scene)
        features = phri.Features(robot, specs, scene=scene)
        xi = random_trajectory(robot, rng, 6)
        expected = reference_per_segment(robot, frame, scene, xi, specs)
        np.testing.assert_allclose(features.per_segment(xi), expected, rtol=1e-12, atol=1e-12, err_msg=frame)
        _, jac = features.phi_gradient(xi)
        np.testing.assert_allclose(jac, fd_gradient(features, xi), rtol=1e-6, atol=1e-6, err_msg=frame)
        checked += int(np.all(expected.sum(axis=0)[:3] != 0.0))
    # The hinged kinds were inside their circles somewhere (not a comparison of zeros).
    assert checked >= len(robot.frame_names) // 2, checked


@pytest.mark.parametrize(
    ("spec", "error", "pattern"),
    [
        ({"kind": "hieght"}, ex.UnknownNameError, r"features\[1\]\.kind: unknown feature kind 'hieght'"),
        (
            {"kind": "height", "frame": "link_99"},
            ex.UnknownNameError,
            r"features\[1\]\.frame: unknown frame 'link_99'",
        ),
        ({"kind": "height", "object": "sofa"}, ex.UnknownNameError, r"sofa"),
        ({"kind": "distance", "object": "laptop"}, ex.InvalidParameterError, r"features\[1\]\.radius"),
        ({"kind": "distance", "object": "laptop", "radius": -1.0}, ex.InvalidParameterError, r"radius"),
        (
            {"kind": "distance", "object": "laptop", "radius": 0.2, "shape": "cone"},
            ex.InvalidParameterError,
            "shape",
        ),
        ({"kind": "alignment", "direction": (0, 0, 0)}, ex.InvalidParameterError, r"direction"),
        ({"kind": "alignment", "direction": (0, 0, 1), "axis": "w"}, ex.InvalidParameterError, r"axis"),
        ({"kind": "joint_distance", "pose": (0.0, 1.0)}, ex.ShapeError, r"features\[1\]\.pose"),
        ({"kind": "speed", "radius": 1.0}, ex.InvalidParameterError, r"takes no parameter 'radius'"),
    ],
)
def test_declared_kinds_refuse_bad_parameters_naming_them(spec, error, pattern):
    robot, scene = phri.Robot.jaco2(), phri.load_task("table").scene
    with pytest.raises(error, match=pattern):
        phri.Features(robot, ["efficiency", {"name": "mine", **spec}], scene=scene)


class PythonTable(phri.Feature):
    """The built-in table feature in numpy: the feature frame's height above `height` [m]."""

    name = "table"

    def __init__(self, robot: phri.Robot, height: float = 0.0, gradient: bool = True) -> None:
        self.robot, self.frame, self.height = robot, robot.feature_frame, height
        self.calls = 0
        if not gradient:
            self.gradient = None

    def value(self, q):
        self.calls += 1
        return self.robot.frame_pose(self.frame, q)[:, 2, 3] - self.height

    def gradient(self, q):  # type: ignore[override]
        return self.robot.jacobian(self.frame, q)[:, 2, :]


@pytest.fixture(scope="module")
def table_task():
    return phri.load_task("table")


def test_a_python_table_gives_the_builtins_phi_plan_and_learning(table_task):
    robot = phri.Robot.jaco2()
    height = dict(table_task.features[1].params).get("height", 0.0)
    builtin = table_task.feature_set(robot)
    mine = PythonTable(robot, height)
    python = phri.Features(robot, ["efficiency", mine], scene=table_task.scene)
    xi = random_trajectory(robot, np.random.default_rng(1), 31)
    np.testing.assert_allclose(python.phi(xi), builtin.phi(xi), rtol=0, atol=1e-12)
    w = table_task.vector("true")
    plans = []
    for features in (builtin, python):
        opt = phri.TrajectoryOptimizer(features, 31, duration=table_task.duration, knots=table_task.knots)
        plan, info = opt.solve(w, table_task.start, table_task.goal)
        assert info.converged and info.feasible, info
        plans.append((plan, info))
    (_, a), (_, b) = plans
    assert abs(a.cost - b.cost) <= 1e-6 * abs(a.cost), (a.cost, b.cost)
    # The planner called Python once per evaluation (and per derivative), not per waypoint.
    assert 0 < mine.calls <= 2 * b.evaluations + 4 * (b.iterations + b.coarse_iterations), (mine.calls, b)
    # The learner learns its weight from a push as it learns the built-in's.
    learned = [learn_from_a_push(robot, features, table_task) for features in (builtin, python)]
    (w0, plan0), (w1, plan1) = learned
    assert w0[1] > 0.1, "the push taught the table's weight"
    np.testing.assert_allclose(w1, w0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(plan1, plan0, rtol=0, atol=1e-4)


def learner_for(features: phri.Features, task, **kwargs) -> phri.Learner:
    opt = phri.TrajectoryOptimizer(features, task.waypoints, duration=task.duration)
    update = phri.WeightUpdate(
        task.vector("step"),
        task.vector("lower"),
        task.vector("upper"),
        learned=[f.learned for f in task.features],
    )
    return phri.Learner(
        features, phri.Deformation(), update, phri.InteractionDetector(), opt, task.vector("initial"),
        task.start, task.goal, duration=task.duration, **kwargs,
    )  # fmt: skip


def push(robot: phri.Robot, learner: phri.Learner, t: float) -> np.ndarray:
    q, _, _ = learner.reference(t)
    return robot.jacobian(robot.hand_frame, q).T @ np.array([0.0, 0.0, -25.0, 0.0, 0.0, 0.0])


def learn_from_a_push(robot, features, task):
    learner = learner_for(features, task)
    for k in range(3000, 4600):
        t = k * TICK
        learner.observe(t, push(robot, learner, t) if 4000 <= k < 4500 and k % 100 == 0 else np.zeros(7))
    return learner.weights, learner.plan


def test_a_feature_without_gradient_is_differentiated_by_finite_differences(table_task):
    robot = phri.Robot.jaco2()
    exact = phri.Features(robot, ["efficiency", PythonTable(robot)])
    approx = phri.Features(robot, ["efficiency", PythonTable(robot, gradient=False)])
    xi = random_trajectory(robot, np.random.default_rng(2), 11)
    np.testing.assert_allclose(approx.phi_gradient(xi)[1], exact.phi_gradient(xi)[1], rtol=0, atol=1e-8)
    opt = phri.TrajectoryOptimizer(approx, 31, duration=15.0)
    _, info = opt.solve([1.0, 1.0], table_task.start, table_task.goal)
    assert info.converged, info


def bad(kind: str) -> phri.Feature:
    def value(q):
        if kind == "shape":
            return np.zeros((len(q), 2))
        if kind == "nan":
            return np.full(len(q), np.nan)
        if kind == "raises":
            return 1.0 / 0.0
        if kind == "slow":
            time.sleep(0.06)
        if kind == "text":
            return "tall"
        return np.zeros(len(q))

    return phri.feature("wobbly", value, timeout=0.05)


@pytest.mark.parametrize(
    ("kind", "pattern"),
    [
        ("shape", r"'wobbly': value\(q\) must return shape \(30,\) for q of shape \(30, 7\), got \(30, 2\)"),
        ("nan", r"feature 'wobbly': the value is not finite at configuration 0"),
        ("raises", r"'wobbly': value\(q\) raised ZeroDivisionError: .*zero \(.*user_features\.py:\d+\)"),
        ("slow", r"'wobbly': value\(q\) took 0\.\d+ s for 30 configurations, over its limit of 0\.05 s"),
        ("text", r"feature 'wobbly': value\(q\) must return an array of shape \(30,\)"),
    ],
)  # fmt: skip
def test_a_bad_python_feature_is_a_typed_error_naming_it(kind, pattern, table_task):
    robot = phri.Robot.jaco2()
    features = phri.Features(robot, ["efficiency", bad(kind)])
    xi = np.linspace(table_task.start, table_task.goal, 31)
    with pytest.raises(ex.FeatureError, match=pattern):
        features.phi(xi)
    opt = phri.TrajectoryOptimizer(features, 31, duration=15.0)
    with pytest.raises(ex.FeatureError, match="feature 'wobbly'"):
        opt.solve([1.0, 1.0], table_task.start, table_task.goal)
    # Its weight at 0, the planner never calls it.
    _, info = opt.solve([1.0, 0.0], table_task.start, table_task.goal)
    assert info.converged


def test_python_features_that_are_not_features_are_refused():
    robot = phri.Robot.jaco2()
    with pytest.raises(TypeError, match="non-empty string"):
        phri.feature("", np.sum)

    class Nameless(phri.Feature):
        def value(self, q):
            return np.zeros(len(q))

    with pytest.raises(
        ex.InvalidParameterError, match=r"features\[1\]: a Python feature's `name` must not be empty"
    ):
        phri.Features(robot, ["efficiency", Nameless()])
    with pytest.raises(ex.InvalidParameterError, match=r"features\[1\]\.timeout"):
        phri.Features(robot, ["efficiency", phri.feature("t", np.sum, timeout=-1.0)])
    with pytest.raises(ex.InvalidParameterError, match="lists 'table' twice"):
        phri.Features(robot, ["table", PythonTable(robot)])


class FailsOnTheWorker(PythonTable):
    """The table feature, raising when called from any thread but the main one (the replan worker)."""

    def value(self, q):
        if threading.current_thread() is not threading.main_thread():
            raise RuntimeError("the lab's sensor is offline")
        return super().value(q)


def test_a_correction_whose_python_feature_raises_on_the_worker_is_rejected_and_logged(table_task):
    """The worker learns from the correction (ΔΦ calls the feature) before it replans: the
    correction teaches nothing, the arm keeps its plan, and the history says why."""
    robot = phri.Robot.jaco2()
    features = phri.Features(robot, ["efficiency", FailsOnTheWorker(robot)], scene=table_task.scene)
    learner = learner_for(features, table_task, replan_latency=0.01)
    plan0, weights0 = learner.plan, learner.weights
    for k in range(3900, 4300):
        t = k * TICK
        learner.observe(t, push(robot, learner, t) if k == 4000 else np.zeros(7))
    np.testing.assert_array_equal(learner.plan, plan0)
    np.testing.assert_array_equal(learner.weights, weights0)
    history = learner.history()
    assert len(history) == 1 and history.updates == [None], "the push is recorded, without an update"
    assert len(history.rejected) == 1, history.rejected
    assert history.rejected[0].startswith("learning failed: ")
    assert "feature 'table'" in history.rejected[0] and "the lab's sensor is offline" in history.rejected[0]
    # The same feature inline, on the main thread, learns.
    inline = learner_for(features, table_task, replan_latency=0.0)
    for k in range(3900, 4300):
        t = k * TICK
        inline.observe(t, push(robot, inline, t) if k == 4000 else np.zeros(7))
    assert inline.weights[1] > weights0[1]


# --------------------------------------------------------------------------------------------------
# task files


FEATURE_CODE = '''
import phri


class Table(phri.Feature):
    """The table feature, written by the lab."""

    def __init__(self, robot, height=0.0):
        self.robot, self.frame, self.height = robot, robot.feature_frame, height

    def value(self, q):
        return self.robot.frame_pose(self.frame, q)[:, 2, 3] - self.height

    def gradient(self, q):
        return self.robot.jacobian(self.frame, q)[:, 2, :]
'''


def lab_task(folder: Path, table: str, name: str = "lab_table") -> Path:
    """The shipped table task with its table feature replaced by `table` (a TOML table's body)."""
    text = (Path(phri.__file__).parent / "tasks" / "table.toml").read_text()
    text = text.replace('name = "table"', f'name = "{name}"').replace(
        'task_feature = "table"', 'task_feature = "mine"'
    )
    head, rest = text.split("[features.table]\n", 1)
    rest = rest.split("\n\n", 1)[1]
    weights = "initial = 0.0\ntrue = 1.0\nstep = 2.0\nlower = 0.0\nupper = 1.0\n"
    path = folder / f"{name}.toml"
    path.write_text(f"{head}[features.mine]\n{table}\n{weights}\n{rest}")
    return path


def write_lab(folder: Path) -> None:
    (folder / "mylab").mkdir(exist_ok=True)
    (folder / "mylab" / "features.py").write_text(FEATURE_CODE)


def test_task_files_declare_features_and_name_python_code(tmp_path, table_task):
    write_lab(tmp_path)
    robot = phri.Robot.jaco2()
    xi = np.linspace(table_task.start, table_task.goal, 31)
    builtin = table_task.feature_set(robot).phi(xi)
    declared = phri.load_task(lab_task(tmp_path, 'kind = "height"'))
    python = phri.load_task(lab_task(tmp_path, 'source = "mylab.features:Table"', "lab_python"))
    for task in (declared, python):
        assert task.feature_names == ["efficiency", "mine"]
        np.testing.assert_allclose(task.feature_set(robot).phi(xi), builtin, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("table", "pattern"),
    [
        ('source = "mylab.missing:Table"', r"features\.mine\.source.*no module file .*mylab/missing\.py"),
        ('source = "mylab.features:Chair"', r"mylab/features\.py defines no 'Chair'"),
        ('source = "mylab.features"', r"must be 'module:Name'"),
        ('source = "os:system"', r"no module file .*os\.py"),
        ('source = "mylab.features:Table"\nargs = { colour = "red" }', r"Table\(\*\*args\) raised TypeError"),
        ('kind = "height"\nsource = "mylab.features:Table"', r"either kind or source"),
        ('kind = "hight"', r"features\.mine\.kind': unknown kind 'hight'.*did you mean 'height'"),
        ('kind = "distance"\nobject = "sofa"\nradius = 0.2', r"features\.mine\.object.*\[scene\]"),
        ('kind = "distance"\nobject = "laptop"', r"missing key 'features\.mine\.radius'"),
        ('kind = "alignment"\ndirection = [0, 0]', r"features\.mine\.direction.*3 finite numbers"),
        ('kind = "height"\nframe = "elbow"', r"features\[1\]\.frame: unknown frame 'elbow'"),
    ],
)
def test_a_bad_user_feature_in_a_task_file_is_a_config_error(tmp_path, table, pattern):
    write_lab(tmp_path)
    with pytest.raises(ex.ConfigError, match=pattern):
        phri.load_task(lab_task(tmp_path, table))


def test_a_study_with_a_python_feature_runs_resumes_and_reports(tmp_path, capsys):
    lab = tmp_path / "lab"
    lab.mkdir()
    write_lab(lab)
    task = lab_task(lab, 'source = "mylab.features:Table"\nargs = { height = 0.0 }')
    run = tmp_path / "run"
    argv = ["study", str(run), "--participants", "2", "--attempts", "1", "--tasks", str(task),
            "--familiarization", "none", "--no-progress", "--backend", "serial",
            "--max-episodes", "2"]  # fmt: skip
    assert phri_main(argv) == 0
    assert (run / "tasks" / "mylab" / "features.py").read_text() == FEATURE_CODE
    assert phri_main(["study", str(run), "--no-progress", "--backend", "serial"]) == 0  # resumes
    rows = list(csv.DictReader((run / "results.csv").read_text().splitlines()))
    assert len(rows) == 4 and all(r["status"] == "ok" for r in rows), rows
    # The simulated people corrected the lab's feature: they pushed, and learning moved its weight.
    assert all(float(r["effort"]) > 0 for r in rows)
    assert all(float(r["final_weight"]) > 0.1 for r in rows if r["strategy"] == "learning")
    assert phri_main(["report", str(run)]) == 0
    assert (run / "report" / "report.md").is_file()


def test_a_declared_distance_is_a_keep_out_circle_like_the_builtin():
    task = phri.load_task("laptop")
    robot = phri.Robot.jaco2()
    (centre, radius) = task.keep_out_circle("laptop")
    declared = {
        "name": "mine",
        "kind": "distance",
        "object": "laptop",
        "radius": 0.4,
        "offset": (0.0, -0.1, 0.0),
    }
    circles = phri.Features(robot, ["efficiency", declared], scene=task.scene).keep_out_circles
    np.testing.assert_allclose(circles["mine"][0], centre, rtol=0, atol=1e-12)
    assert circles["mine"][1] == radius
    ball = {**declared, "shape": "sphere"}
    assert phri.Features(robot, ["efficiency", ball], scene=task.scene).keep_out_circles == {}
