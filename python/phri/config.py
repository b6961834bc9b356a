"""Task files: validated, frozen configuration loaded from TOML.

A task names its start and goal poses, its duration, and per feature the initial weight, the true
(demonstrated) weight, the learning step and the bounds. The study's four tasks ship with phri
(``phri.load_task("table")``); a user passes their own file the same way (``load_task("my.toml")``).
Errors name the file, the key and the expected value.
"""

from __future__ import annotations

import difflib
import functools
import math
import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from phri._phri import Robot
from phri.exceptions import ConfigError, UnknownNameError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["FeatureSpec", "Scene", "Task", "load_task", "task_names"]

STUDY_TASKS = ("human", "coffee", "table", "laptop")
KNOWN_FEATURES = ("efficiency", "table", "coffee", "coffee_dot", "laptop", "human", "origin")
TASK_KEYS = (
    "name", "title", "angles", "start", "goal", "duration", "waypoints", "task_feature", "features", "scene",
)  # fmt: skip
FEATURE_KEYS = ("initial", "true", "step", "lower", "upper", "learned")
SCENE_KEYS = ("table_height", "laptop_center", "human_center", "laptop_radius", "human_radius", "samples")


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


@dataclass(frozen=True)
class Scene:
    """Where the objects are, in the robot base frame [m] (original_system.md)."""

    table_height: float = -0.1016
    laptop_center: tuple[float, float] = (-0.7929, -0.1)
    human_center: tuple[float, float] = (0.0, 0.2)
    laptop_radius: float = 0.4
    human_radius: float = 0.4
    samples: int = 4


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

    @property
    def feature_names(self) -> list[str]:
        return [f.name for f in self.features]

    def vector(self, attribute: str) -> np.ndarray:
        """One attribute of every feature as an array, e.g. ``task.vector("true")``."""
        return np.array([getattr(f, attribute) for f in self.features], dtype=float)

    @property
    def task_index(self) -> int:
        return self.feature_names.index(self.task_feature)


def task_names() -> list[str]:
    """Names of the tasks shipped with phri."""
    folder = resources.files("phri").joinpath("tasks")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def _finite(x: Any) -> bool:
    """A TOML number (not a boolean) that is finite as a float (huge integers are not)."""
    if isinstance(x, bool) or not isinstance(x, int | float):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def _unknown_key(source: str, path: str, key: str, allowed: tuple[str, ...]) -> ConfigError:
    """An error for `key` in the table at `path` ("" for the top level): the allowed keys, a near match."""
    table = f"table [{path}]" if path else "the top-level table"
    full = f"{path}.{key}" if path else key
    close = difflib.get_close_matches(key, allowed, n=1)
    hint = f"; did you mean '{close[0]}'?" if close else ""
    return ConfigError(f"{source}: unknown key '{full}' in {table}; allowed keys: {', '.join(allowed)}{hint}")


class _Reader:
    """Typed access to a TOML table with errors that name the file and key.

    With `allowed`, a key the table does not know is an error (a typo must not fall back to a default).
    """

    def __init__(
        self, source: str, table: dict[str, Any], prefix: str = "", allowed: tuple[str, ...] | None = None
    ) -> None:
        self.source, self.table, self.prefix = source, table, prefix
        if allowed is not None:
            for key in table:
                if key not in allowed:
                    raise _unknown_key(source, prefix.rstrip("."), key, allowed)

    def fail(self, key: str, expected: str, got: Any = None) -> ConfigError:
        got_text = "" if got is None else f", got {got!r}"
        return ConfigError(f"{self.source}: key '{self.prefix}{key}' must be {expected}{got_text}")

    def get(self, key: str, default: Any = ...) -> Any:
        if key in self.table:
            return self.table[key]
        if default is ...:
            raise ConfigError(f"{self.source}: missing key '{self.prefix}{key}'")
        return default

    def number(
        self, key: str, default: Any = ..., positive: bool = False, expected: str = "a finite number"
    ) -> float:
        """A finite number from the file; a default that is not in the file may be infinite."""
        if key not in self.table and default is not ...:
            return float(default)
        v = self.get(key)
        if not _finite(v):
            raise self.fail(key, expected, v)
        if positive and not v > 0:
            raise self.fail(key, "a number > 0", v)
        return float(v)

    def string(self, key: str, default: Any = ...) -> str:
        v = self.get(key, default)
        if not isinstance(v, str):
            raise self.fail(key, "a string", v)
        return v

    def vector(self, key: str, length: int, default: Any = ...) -> np.ndarray:
        v = self.get(key, default)
        ok = isinstance(v, list | tuple) and len(v) == length and all(_finite(x) for x in v)
        if not ok:
            raise self.fail(key, f"a list of {length} finite numbers", v)
        return np.asarray(v, dtype=float)

    def table_of(self, key: str, allowed: tuple[str, ...]) -> _Reader:
        """The sub-table `key` (empty if absent), its keys checked against `allowed`."""
        v = self.get(key, {})
        if not isinstance(v, dict):
            raise self.fail(key, f"a table, e.g. [{self.prefix}{key}]", v)
        return _Reader(self.source, v, f"{self.prefix}{key}.", allowed)


@functools.cache
def _robot() -> Robot:
    """The robot every task drives (task files cannot name another one)."""
    return Robot.jaco2()


def _format_angle(value: float) -> str:
    return f"{value:.6f}".rstrip("0").rstrip(".")


def _check_limits(r: _Reader, key: str, q: np.ndarray, scale: float, unit: str) -> None:
    """`q` [rad] within the robot's joint limits, as Planner checks it; the error is in the file's unit."""
    robot = _robot()
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


def _parse(data: dict[str, Any], source: str) -> Task:
    r = _Reader(source, data, allowed=TASK_KEYS)
    angles = r.string("angles", "radians")
    if angles not in ("degrees", "radians"):
        raise r.fail("angles", "'degrees' or 'radians'", angles)
    scale = math.pi / 180.0 if angles == "degrees" else 1.0
    start, goal = r.vector("start", 7) * scale, r.vector("goal", 7) * scale
    _check_limits(r, "start", start, scale, angles)
    _check_limits(r, "goal", goal, scale, angles)
    waypoints = r.get("waypoints", 31)
    if isinstance(waypoints, bool) or not isinstance(waypoints, int) or waypoints < 3:
        raise r.fail("waypoints", "an integer >= 3", waypoints)
    feats = r.get("features")
    if not isinstance(feats, dict) or not feats:
        raise r.fail("features", "a table of feature tables, e.g. [features.table]", feats)
    specs = []
    for name, table in feats.items():
        if name not in KNOWN_FEATURES:
            close = difflib.get_close_matches(name, KNOWN_FEATURES, n=1)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            raise ConfigError(
                f"{source}: key 'features.{name}': unknown feature; known: {', '.join(KNOWN_FEATURES)}{hint}"
            )
        if not isinstance(table, dict):
            raise r.fail(f"features.{name}", "a table", table)
        f = _Reader(source, table, f"features.{name}.", FEATURE_KEYS)
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
        specs.append(FeatureSpec(name, initial, true, step, lower, upper, learned))
    task_feature = r.string("task_feature")
    if task_feature not in feats:
        raise r.fail("task_feature", f"one of the task's features {list(feats)}", task_feature)
    s = r.table_of("scene", SCENE_KEYS)
    samples = s.get("samples", 4)
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise s.fail("samples", "an integer >= 1", samples)
    scene = Scene(
        table_height=s.number("table_height", Scene.table_height),
        laptop_center=tuple(s.vector("laptop_center", 2, list(Scene.laptop_center))),  # type: ignore[arg-type]
        human_center=tuple(s.vector("human_center", 2, list(Scene.human_center))),  # type: ignore[arg-type]
        laptop_radius=s.number("laptop_radius", Scene.laptop_radius, positive=True),
        human_radius=s.number("human_radius", Scene.human_radius, positive=True),
        samples=samples,
    )
    return Task(
        name=r.string("name"),
        title=r.string("title", ""),
        start=start,
        goal=goal,
        duration=r.number("duration", 15.0, positive=True),
        waypoints=waypoints,
        task_feature=task_feature,
        features=tuple(specs),
        scene=scene,
        source=source,
    )


def _read_text(source: str, file: Any) -> str:
    """The text of a task file (a Path or a package resource); not UTF-8 is a ConfigError."""
    raw = file.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise ConfigError(
            f"{source}: not UTF-8 text (line {line}, byte {e.start}: {raw[e.start : e.end]!r}); "
            "save the task file as UTF-8"
        ) from None
    return text.replace("\r\n", "\n").replace("\r", "\n")  # universal newlines, as read_text


def load_task(name_or_path: str | Path) -> Task:
    """A shipped task by name (``"human"``, ``"coffee"``, ``"table"``, ``"laptop"``) or a TOML file."""
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists():
        if not path.is_file():
            raise ConfigError(f"{path}: task file not found")
        source, text = str(path), _read_text(str(path), path)
    else:
        name = str(name_or_path)
        if name not in task_names():
            raise UnknownNameError(f"task: unknown task '{name}'; known: {', '.join(task_names())}")
        res = resources.files("phri").joinpath("tasks", f"{name}.toml")
        source = f"phri/tasks/{name}.toml"
        text = _read_text(source, res)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{source}: not valid TOML ({e})") from None
    return _parse(data, source)
