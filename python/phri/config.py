"""Task files: validated, frozen configuration loaded from TOML.

A task names its start and goal poses, its duration, per feature the initial weight, the true
(demonstrated) weight, the learning step, the bounds and the feature's own parameters (a keep-out
feature names the scene object it keeps away from), its scene: one ``[scene.<name>]`` table per
object, in the robot's base frame, and the limits of the control loop's safety layer for the task
(``[safety]``: the box the tool point must stay in, and tighter joint limits than the robot's).
The study's four tasks ship with phri (``phri.load_task("table")``); a user passes their own file
the same way (``load_task("my.toml")``). Errors name the file, the key and the expected value.
"""

from __future__ import annotations

import functools
import math
import os
import stat
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from phri._phri import (
    DECLARED_PARAMETERS,
    FEATURE_NAMES,
    FEATURE_PARAMETERS,
    Features,
    Robot,
    Scene,
    SceneObject,
    TrajectoryOptimizer,
)
from phri._validate import Reader, decode_utf8, did_you_mean, is_integer, parse_toml
from phri.exceptions import ConfigError, PhriError, UnknownNameError
from phri.feature import load_feature, source_file
from phri.robots import SAFETY_KEYS, SafetySpec, read_safety

__all__ = ["FeatureSpec", "Task", "TaskSafety", "load_task", "task_names"]

STUDY_TASKS = ("human", "coffee", "table", "laptop")
#: A task's name names its log and figure files: at most this many characters, each a letter, a
#: digit or one of NAME_PUNCTUATION.
MAX_NAME_LENGTH = 64
NAME_PUNCTUATION = ("_", "-", ".")
TASK_KEYS = (
    "name", "title", "angles", "start", "goal", "duration", "waypoints", "knots", "task_feature",
    "feature_frame", "features", "unmodelled", "scene", "robot", "safety",
)  # fmt: skip
#: Keys of a task's [safety] table: the tool's box and overrides of the robot's joint limits.
TASK_SAFETY_KEYS = ("tool_box", *SAFETY_KEYS)
#: Keys of a [features.<name>] table besides the feature's own parameters (FEATURE_PARAMETERS).
WEIGHT_KEYS = ("initial", "true", "step", "lower", "upper", "learned")
SCENE_OBJECT_KEYS = ("shape", "size", "radius", "length", "position", "rpy", "margin", "kind")
#: The planner keeps the hand and the cup above the top of the scene object of this name.
TABLE = "table"


@dataclass(frozen=True)
class FeatureSpec:
    """One feature of a task's objective (cost weights)."""

    name: str
    initial: float
    true: float
    step: float = 0.0
    lower: float = 0.0
    upper: float = math.inf
    learned: bool = True
    #: The feature's own parameters (FEATURE_PARAMETERS[name]), e.g. a keep-out feature's
    #: keep_out, radius [m], offset [m] and samples; a declared feature's ``kind`` and that kind's
    #: parameters (DECLARED_PARAMETERS[kind]); a Python feature's ``source``, the ``folder`` it is
    #: looked up in and its ``args``.
    params: dict[str, Any] = field(default_factory=dict)

    def code(self) -> tuple[Path, str] | None:
        """A Python feature's module file and its path relative to the task file's folder (None
        for a built-in or declared feature): a study copies it beside its copy of the task file."""
        if "source" not in self.params:
            return None
        folder = Path(self.params["folder"])
        path, _ = source_file(self.params["source"], folder)
        return path, path.relative_to(folder).as_posix()

    def feature(self, robot: Robot | None = None, scene: Scene | None = None) -> Any:
        """The item of ``phri.Features(robot, features)`` for this feature: a name, a mapping, or
        (``source``) the Python feature the task file names, made for `robot` and `scene`."""
        if "source" in self.params:
            p = self.params
            return load_feature(p["source"], Path(p["folder"]), self.name, p["args"], robot, scene)
        return {"name": self.name, **self.params} if self.params else self.name


@dataclass(frozen=True)
class TaskSafety:
    """A task's ``[safety]`` table: the box the tool point (the robot's hand frame) must stay in
    while the arm runs, ``tool_box = { lower = [x, y, z], upper = [x, y, z] }`` [m, base frame] (None:
    no box), and joint limits tighter than the robot description's (`limits`, the keys of
    :class:`phri.robots.SafetySpec`; a task may only tighten them)."""

    tool_box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    limits: SafetySpec = field(default_factory=SafetySpec)


@dataclass(frozen=True)
class Task:
    """A validated task; angles are in radians whatever the file used."""

    name: str
    title: str
    start: np.ndarray
    goal: np.ndarray
    duration: float
    waypoints: int
    task_feature: str
    features: tuple[FeatureSpec, ...]
    scene: Scene = field(default_factory=Scene)
    source: str = "<memory>"
    #: The frame the features read (None: the robot's feature frame).
    feature_frame: str | None = None
    #: The shipped robot the task is posed for ("jaco2" when the file names none).
    robot: str = "jaco2"
    #: The task's [safety] table (the tool's box, tighter joint limits).
    safety: TaskSafety = field(default_factory=TaskSafety)
    #: Plan by this many knots (``phri.TrajectoryOptimizer(knots=...)``: piecewise linear through
    #: knots evenly spaced in time, each on a waypoint, as the original planned 4 and upsampled them
    #: to 31); 0 plans every waypoint.
    knots: int = 0
    #: Features the simulated person cares about and the robot does not model (``[unmodelled.<name>]``
    #: tables, each with its ``true`` weight): the person's desired behaviour is planned with them
    #: too, and they correct for them; the robot's features, learner and planner never see them
    #: (misspecified features, Bobu et al., T-RO 2020). ``initial`` is 0 and ``learned`` true.
    unmodelled: tuple[FeatureSpec, ...] = ()

    def seen_by_person(self) -> Task:
        """The task as the simulated person sees it: its features followed by the unmodelled ones
        (the task itself when there are none)."""
        if not self.unmodelled:
            return self
        return replace(self, features=(*self.features, *self.unmodelled), unmodelled=())

    @property
    def feature_names(self) -> list[str]:
        """The features' names, in the order of the weight vectors."""
        return [f.name for f in self.features]

    def vector(self, attribute: str) -> np.ndarray:
        """One attribute of every feature as an array, e.g. ``task.vector("true")``."""
        return np.array([getattr(f, attribute) for f in self.features], dtype=float)

    @property
    def task_index(self) -> int:
        """Index of the task's own feature (the one the person teaches) in the weight vectors."""
        return self.feature_names.index(self.task_feature)

    def feature_set(self, robot: Robot, *, ranges: Any = None) -> Features:
        """The task's features over `robot`, keep-out features placed by the task's scene; a robot
        other than the task's is a ConfigError."""
        if robot.name != _robot(self.robot).name:
            raise ConfigError(
                f"{self.source}: task '{self.name}' is posed for robot '{self.robot}', not {robot.name}"
            )
        return Features(
            robot,
            [f.feature(robot, self.scene) for f in self.features],
            scene=self.scene,
            frame=self.feature_frame,
            ranges=ranges,
        )

    def keep_out_circle(self, feature: str) -> tuple[tuple[float, float], float] | None:
        """Centre (x, y) [m] and radius [m] of keep-out feature `feature`'s circle (None if the task
        has no such keep-out feature)."""
        return self.feature_set(_robot(self.robot)).keep_out_circles.get(feature)


def task_names() -> list[str]:
    """Names of the tasks shipped with phri."""
    folder = resources.files("phri").joinpath("tasks")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


@functools.cache
def _robot(name: str = "jaco2") -> Robot:
    """The shipped robot `name` a task is posed for."""
    return Robot.from_description(name)


def _format_angle(value: float) -> str:
    return f"{value:.6f}".rstrip("0").rstrip(".")


def _check_limits(r: Reader, key: str, q: np.ndarray, scale: float, unit: str) -> None:
    """`q` [rad] within the robot's joint limits, as Planner checks it; the error is in the file's unit."""
    robot_name = r.string("robot", "jaco2")
    try:
        robot = _robot(robot_name)
    except PhriError as e:
        raise r.fail("robot", "the name of a shipped robot (e.g. 'jaco2', 'fr3')", robot_name) from e
    lower, upper = robot.lower_limits, robot.upper_limits
    raw = r.get(key)
    bad = [
        f"{key}[{j}] = {raw[j]!r} is outside [{_format_angle(lower[j] / scale)}, "
        f"{_format_angle(upper[j] / scale)}] (joint '{robot.joint_names[j]}')"
        for j in range(q.size)
        if q[j] < lower[j] or q[j] > upper[j]
    ]
    if bad:
        raise ConfigError(
            f"{r.source}: key '{r.prefix}{key}' must be within the joint limits of {robot.name} "
            f"in {unit}: {'; '.join(bad)}"
        )


#: How each feature parameter is read from a task file (which feature takes which: FEATURE_PARAMETERS).
_PARAMETER_READERS: dict[str, Any] = {
    "keep_out": lambda f, key: f.string(key),
    "radius": lambda f, key: f.number(key, positive=True),
    "offset": lambda f, key: tuple(float(x) for x in f.vector(key, 2)),
    "samples": lambda f, key: _integer(f, key, 1),
    "height": lambda f, key: f.number(key),
}


def knots_fit(knots: int, waypoints: int) -> bool:
    """Whether a plan of `waypoints` can be planned by `knots` (0: on every waypoint): each knot on a
    waypoint, as ``phri.TrajectoryOptimizer(knots=...)`` requires (knots − 1 divides waypoints − 1)."""
    return knots == 0 or (3 <= knots < waypoints and (waypoints - 1) % (knots - 1) == 0)


def knots_expected(waypoints: int) -> str:
    """What `knots` may be for a plan of `waypoints`, for a message."""
    fitting = [k for k in range(3, waypoints) if knots_fit(k, waypoints)]
    return f"0 (plan every waypoint) or a knot count with every knot on one of the {waypoints} waypoints " + (
        f"({', '.join(map(str, fitting))})" if fitting else "(none fits)"
    )


def _integer(r: Reader, key: str, minimum: int, default: Any = ..., maximum: int | None = None) -> int:
    v = r.get(key, default)
    if maximum is not None and (not is_integer(v) or not minimum <= v <= maximum):
        raise r.fail(key, f"an integer in {minimum}..={maximum}", v)
    if not is_integer(v) or v < minimum:
        raise r.fail(key, f"an integer >= {minimum}", v)
    return v


def _name(r: Reader, key: str, known: tuple[str, ...], what: str) -> str:
    """A string from `known` (e.g. a shape), with a near match when misspelt."""
    v = r.string(key)
    if v not in known:
        raise ConfigError(
            f"{r.source}: key '{r.prefix}{key}' must be {what}: {', '.join(known)}, got {v!r}"
            f"{did_you_mean(v, known)}"
        )
    return v


def _scene(r: Reader) -> Scene:
    """The [scene.<name>] tables, each one object in the robot's base frame."""
    objects = []
    entry = "a table, e.g. [scene.table] with shape, size, position"
    for name, o in r.named_tables("scene", "table", entry, SCENE_OBJECT_KEYS):
        spec = o.table
        shape = _name(o, "shape", tuple(SceneObject.SHAPES), "one of the shapes")
        kwargs: dict[str, Any] = (
            {"kind": _name(o, "kind", tuple(SceneObject.KINDS), "one of")} if "kind" in spec else {}
        )
        for key in ("size", "rpy"):
            if key in spec:
                kwargs[key] = o.vector(key, 3)
        for key in ("radius", "length"):
            if key in spec:
                kwargs[key] = o.number(key, positive=True)
        if "margin" in spec:
            kwargs["margin"] = o.number("margin")
        position = o.vector("position", 3)
        try:
            objects.append(SceneObject(name, shape, position, **kwargs))
        except PhriError as e:  # what a shape needs, and value ranges: the core's checks
            raise ConfigError(f"{r.source}: key 'scene.{name}': {e}") from None
    return Scene(objects)


def _safety(r: Reader) -> TaskSafety:
    """The [safety] table: the tool's box (each corner three finite numbers [m], lower < upper on
    every axis) and the joint-limit overrides."""
    s = r.table_of("safety", TASK_SAFETY_KEYS)
    tool_box = None
    if "tool_box" in s.table:
        expected = "a table { lower = [x, y, z], upper = [x, y, z] } [m] with lower < upper"
        raw = s.get("tool_box")
        if not isinstance(raw, dict):
            raise s.fail("tool_box", expected, raw)
        box = Reader(s.source, raw, "safety.tool_box.", ("lower", "upper"))
        lower, upper = box.vector("lower", 3), box.vector("upper", 3)
        if not (lower < upper).all():
            raise s.fail("tool_box", expected, raw)
        tool_box = (
            (float(lower[0]), float(lower[1]), float(lower[2])),
            (float(upper[0]), float(upper[1]), float(upper[2])),
        )
    return TaskSafety(tool_box, read_safety(s))


def _feature(
    r: Reader, name: str, table: Any, scene: Scene, scale: float, section: str = "features"
) -> FeatureSpec:
    """One [features.<name>] table: the weights and the feature's own parameters; a table with
    ``kind`` declares a feature of that kind, one with ``source`` names a Python feature."""
    if not isinstance(table, dict):
        raise r.fail(f"{section}.{name}", "a table", table)
    if "kind" in table and "source" in table:
        raise ConfigError(f"{r.source}: key '{section}.{name}': give either kind or source, not both")
    if "kind" in table:
        return _declared(r, name, table, scene, scale, section)
    if "source" in table:
        return _python_feature(r, name, table, section)
    if name not in FEATURE_NAMES:
        raise ConfigError(
            f"{r.source}: key '{section}.{name}': unknown feature; known: {', '.join(FEATURE_NAMES)}"
            f"{did_you_mean(name, FEATURE_NAMES)} (or declare one with kind = ..., or name Python code with "
            'source = "module:Name")'
        )
    parameters = FEATURE_PARAMETERS[name]
    f = Reader(r.source, table, f"{section}.{name}.", WEIGHT_KEYS + parameters)
    if "keep_out" in parameters:
        f.get("radius")  # a keep-out feature needs both: a missing one is named here
        _object(f, "keep_out", scene)
    params = {key: _PARAMETER_READERS[key](f, key) for key in parameters if key in table}
    return FeatureSpec(name, *_weights(f, name, table), params)


def _weights(f: Reader, name: str, table: dict[str, Any]) -> tuple[float, float, float, float, float, bool]:
    """(initial, true, step, lower, upper, learned) of a [features.<name>] table."""
    learned = f.get("learned", True)
    if not isinstance(learned, bool):
        raise f.fail("learned", "true or false", learned)
    initial, true = f.number("initial"), f.number("true")
    # A learned weight is clipped to [lower, upper] (default [0, inf)); a fixed one (learned = false)
    # is only checked against the bounds the file gives, and its clip range defaults to [initial].
    lower = f.number("lower", 0.0 if learned else -math.inf)
    upper = f.number("upper", math.inf, expected="a finite number (leave it out for no upper bound)")
    if lower > upper:
        raise f.fail("lower", f"<= upper ({upper})", lower)
    for key, value in (("initial", initial), ("true", true)):
        if not lower <= value <= upper:
            raise f.fail(key, f"within [lower, upper] = [{lower}, {upper}] of feature '{name}'", value)
    if not learned:
        lower = lower if "lower" in table else initial
        upper = upper if "upper" in table else initial
    step = f.number("step", 0.0)
    if step < 0:
        raise f.fail("step", "a number >= 0", step)
    return initial, true, step, lower, upper, learned


def _object(f: Reader, key: str, scene: Scene) -> str:
    """Key `key`: the name of an object of the task's scene."""
    name = f.string(key)
    if name not in scene:
        objects = f"({', '.join(scene.names)})" if len(scene) else "(it has none)"
        raise f.fail(key, f"the name of an object of the task's [scene] {objects}", name)
    return name


#: How each parameter of a declared feature is read (which kind takes which: DECLARED_PARAMETERS);
#: the core checks the values (a frame of the robot, a radius > 0, ...).
_DECLARED_READERS: dict[str, Any] = {
    "frame": lambda f, key, kind, scene, scale: f.string(key),
    "object": lambda f, key, kind, scene, scale: _object(f, key, scene),
    "offset": lambda f, key, kind, scene, scale: (
        f.number(key) if kind == "height" else tuple(float(x) for x in f.vector(key, 3))
    ),
    "radius": lambda f, key, kind, scene, scale: f.number(key, positive=True),
    "samples": lambda f, key, kind, scene, scale: _integer(f, key, 1),
    "shape": lambda f, key, kind, scene, scale: f.string(key),
    "axis": lambda f, key, kind, scene, scale: f.string(key),
    "direction": lambda f, key, kind, scene, scale: tuple(float(x) for x in f.vector(key, 3)),
    "pose": lambda f, key, kind, scene, scale: tuple(float(x) * scale for x in f.vector(key, 7)),
}


def _declared(
    r: Reader, name: str, table: dict[str, Any], scene: Scene, scale: float, section: str = "features"
) -> FeatureSpec:
    """A [features.<name>] table with ``kind``: a declared feature (the kinds: DECLARED_PARAMETERS;
    ``pose`` in the task's angle unit)."""
    kind = table["kind"]
    if kind not in DECLARED_PARAMETERS:
        known = tuple(DECLARED_PARAMETERS)
        raise ConfigError(
            f"{r.source}: key '{section}.{name}.kind': unknown kind {kind!r}; known: {', '.join(known)}"
            f"{did_you_mean(str(kind), known)}"
        )
    parameters = DECLARED_PARAMETERS[kind]
    f = Reader(r.source, table, f"{section}.{name}.", (*WEIGHT_KEYS, "kind", *parameters))
    required = {"distance": ("object", "radius"), "alignment": ("direction",), "joint_distance": ("pose",)}
    for key in required.get(kind, ()):
        f.get(key)
    params = {"kind": kind} | {
        key: _DECLARED_READERS[key](f, key, kind, scene, scale) for key in parameters if key in table
    }
    return FeatureSpec(name, *_weights(f, name, table), params)


def _python_feature(r: Reader, name: str, table: dict[str, Any], section: str = "features") -> FeatureSpec:
    """A [features.<name>] table with ``source = "module:Name"``: Python code beside the task file
    (``args``: keywords for it)."""
    f = Reader(r.source, table, f"{section}.{name}.", (*WEIGHT_KEYS, "source", "args"))
    source = f.string("source")
    path = Path(r.source)
    if not path.is_file():
        raise f.fail("source", "in a task file of your own (a shipped task names no code)", source)
    args = f.get("args", {})
    if not isinstance(args, dict):
        raise f.fail("args", "a table of keyword arguments", args)
    folder = path.resolve().parent
    try:
        source_file(source, folder)
    except ConfigError as e:
        raise ConfigError(f"{r.source}: key '{section}.{name}.source': {e}") from None
    return FeatureSpec(
        name, *_weights(f, name, table), {"source": source, "folder": str(folder), "args": args}
    )


def _parse(data: dict[str, Any], source: str) -> Task:
    r = Reader(source, data, allowed=TASK_KEYS)
    angles = r.string("angles", "radians")
    if angles not in ("degrees", "radians"):
        raise r.fail("angles", "'degrees' or 'radians'", angles)
    scale = math.pi / 180.0 if angles == "degrees" else 1.0
    start, goal = r.vector("start", 7) * scale, r.vector("goal", 7) * scale
    _check_limits(r, "start", start, scale, angles)
    _check_limits(r, "goal", goal, scale, angles)
    waypoints = _integer(r, "waypoints", 3, 31, maximum=TrajectoryOptimizer.MAX_WAYPOINTS)
    knots = r.get("knots", 0)
    if not (is_integer(knots) and knots_fit(knots, waypoints)):
        raise r.fail("knots", knots_expected(waypoints), knots)
    scene = _scene(r)
    feats = r.get("features")
    if not isinstance(feats, dict) or not feats:
        raise r.fail("features", "a table of feature tables, e.g. [features.table]", feats)
    specs = tuple(_feature(r, name, table, scene, scale) for name, table in feats.items())
    unmodelled = _unmodelled(r, specs, scene, scale)
    task_feature = r.string("task_feature")
    if task_feature not in feats:
        raise r.fail("task_feature", f"one of the task's features {list(feats)}", task_feature)
    feature_frame = r.optional_string("feature_frame")
    robot_name = r.string("robot", "jaco2")
    try:
        robot = _robot(robot_name)
    except PhriError as e:
        raise r.fail("robot", "the name of a shipped robot (e.g. 'jaco2', 'fr3')", robot_name) from e
    if feature_frame is not None and feature_frame not in robot.frame_names:
        error = r.fail("feature_frame", f"a frame of {robot.name}", feature_frame)
        raise ConfigError(f"{error}{did_you_mean(feature_frame, robot.frame_names)}")
    task = Task(
        robot=robot_name,
        name=_check_name(source, r.string("name")),
        title=r.string("title", ""),
        start=start,
        goal=goal,
        duration=r.number("duration", 15.0, positive=True),
        waypoints=waypoints,
        knots=int(knots),
        task_feature=task_feature,
        features=specs,
        unmodelled=unmodelled,
        scene=scene,
        source=source,
        feature_frame=feature_frame,
        safety=_safety(r),
    )
    try:  # the core's remaining checks (e.g. at most MAX_SAMPLES samples), named by the file
        task.feature_set(robot)
        if task.unmodelled:
            task.seen_by_person().feature_set(robot)
    except PhriError as e:
        raise ConfigError(f"{source}: {e}") from None
    return task


def _unmodelled(
    r: Reader, specs: tuple[FeatureSpec, ...], scene: Scene, scale: float
) -> tuple[FeatureSpec, ...]:
    """The [unmodelled.<name>] tables: features as in [features], each with only its ``true``
    weight (the person's), none named like a modelled feature."""
    tables = r.get("unmodelled", {})
    if not isinstance(tables, dict):
        raise r.fail("unmodelled", "a table of feature tables, e.g. [unmodelled.laptop]", tables)
    names = {f.name for f in specs}
    out = []
    for name, table in tables.items():
        if name in names:
            raise ConfigError(
                f"{r.source}: key 'unmodelled.{name}': the robot models a feature of that name; an "
                "unmodelled feature needs a name of its own (declare one with kind = ...)"
            )
        if not isinstance(table, dict):
            raise r.fail(f"unmodelled.{name}", "a table", table)
        extra = sorted(set(table) & (set(WEIGHT_KEYS) - {"true"}))
        if extra:
            raise ConfigError(
                f"{r.source}: key 'unmodelled.{name}': only 'true' of the weights applies (the robot never "
                f"learns it), got {extra}"
            )
        spec = _feature(r, name, {**table, "initial": 0.0}, scene, scale, "unmodelled")
        if spec.true == 0.0:
            raise r.fail(f"unmodelled.{name}.true", "a weight other than 0 (the person must care)", spec.true)
        out.append(spec)
    return tuple(out)


def _read_text(source: str, file: Any) -> str:
    """The text of a task file (a Path or a package resource); not UTF-8 is a ConfigError."""
    return decode_utf8(
        file.read_bytes(),
        lambda line, offset, bad: ConfigError(
            f"{source}: not UTF-8 text (line {line}, byte {offset}: {bad!r}); save the task file as UTF-8"
        ),
    )


def load_task(name_or_path: str | Path) -> Task:
    """A shipped task by name (``"human"``, ``"coffee"``, ``"table"``, ``"laptop"``) or a TOML file."""
    if not isinstance(name_or_path, str | os.PathLike):
        raise TypeError(f"name_or_path must be a task name or a path, got {type(name_or_path).__name__}")
    if not str(name_or_path):
        raise UnknownNameError(f"name_or_path: empty; known tasks: {', '.join(task_names())}")
    path = Path(name_or_path)
    if path.suffix == ".toml" or os.path.lexists(path):
        _check_regular_file(path)
        source, text = str(path), _read_text(str(path), path)
    else:
        name = str(name_or_path)
        if name not in task_names():
            raise UnknownNameError(f"task: unknown task '{name}'; known: {', '.join(task_names())}")
        res = resources.files("phri").joinpath("tasks", f"{name}.toml")
        source = f"phri/tasks/{name}.toml"
        text = _read_text(source, res)
    return _parse(parse_toml(text, source, "a task file"), source)


def _check_regular_file(path: Path) -> None:
    """Raises a ConfigError saying what `path` is unless it is a readable regular file: missing, a
    folder, a FIFO or device (reading one would block), a symbolic-link loop."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise ConfigError(f"{path}: task file not found") from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot be read as a task file ({e.strerror})") from None
    if stat.S_ISDIR(mode):
        raise ConfigError(f"{path}: is a folder, not a task file")
    if not stat.S_ISREG(mode):
        raise ConfigError(f"{path}: is not a regular file (a FIFO, socket or device), not a task file")


def _check_name(source: str, name: str) -> str:
    """`name` unless it cannot name files: the task's name goes into log and figure file names."""
    ok = 0 < len(name) <= MAX_NAME_LENGTH and not name.startswith(".")
    if not ok or not all(c.isalnum() or c in NAME_PUNCTUATION for c in name):
        raise ConfigError(
            f"{source}: name must be 1-{MAX_NAME_LENGTH} letters, digits and {' '.join(NAME_PUNCTUATION)} "
            f"(it names files), not starting with '.', got {name[:80]!r}"
        )
    return name
