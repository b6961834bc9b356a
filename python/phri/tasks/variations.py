"""Variations of a task, for tests and for checking a study off the paper's exact scenes.

``phri.tasks.vary(task, rng)`` moves what lies on the table within reach and the person beside it,
raises or lowers the table (with what lies on it and the tool's box), turns the start and goal poses
a little, and optionally adds a second learned feature, then checks the result is a task the study
can run: the plans for the true and the initial weights keep the arm clear and converge, within the
joint limits and the tool's box. A draw that fails is drawn again; after ``attempts`` draws a
PlanningError says why the last one failed.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from phri._phri import Scene, SceneObject
from phri.config import TABLE, FeatureSpec, Task, TaskSafety, _robot, load_task
from phri.exceptions import InvalidParameterError, PhriError, PlanningError

__all__ = ["SECOND_FEATURE", "vary"]

#: The second learned feature ``vary(..., second=True)`` adds, by task feature: the cup's tilt
#: (the coffee task's feature) to the others, the table's height to the coffee task. True weight and
#: step are those of the task that owns the feature; it is learned from 0.
SECOND_FEATURE = {"coffee": ("table", "table")}
_DEFAULT_SECOND = ("coffee", "coffee")


def _moved(obj: SceneObject, shift: np.ndarray) -> SceneObject:
    given, kwargs = obj.__getnewargs_ex__()
    args = list(given)
    args[2] = np.asarray(obj.position, dtype=float) + shift
    return SceneObject(*args, **kwargs)


def _on_table(obj: SceneObject, table: SceneObject) -> bool:
    """Whether `obj` lies on the table: above its top, within its extent in x and y."""
    if obj.name == table.name or obj.kind != "furniture" or table.size is None or table.top is None:
        return False
    half = np.asarray(table.size[:2]) / 2.0
    inside = np.all(np.abs(obj.position[:2] - table.position[:2]) <= half)
    return bool(inside and obj.position[2] >= table.top - 1e-9)


def _scene(
    task: Task, rng: np.random.Generator, move: float, table_height: float
) -> tuple[Scene, float, str]:
    """The task's scene with objects on the table moved up to `move` [m] in x and y (staying on it),
    the table with them raised by up to ±`table_height` [m] and a person moved up to `move` in x and
    y; the rise [m] and what moved."""
    scene = task.scene
    table = scene.get(TABLE)
    rise = float(rng.uniform(-table_height, table_height)) if table is not None and table_height > 0 else 0.0
    objects, said = [], []
    for obj in scene.objects:
        shift = np.zeros(3)
        if table is not None and (obj.name == TABLE or _on_table(obj, table)):
            shift[2] = rise
        if table is not None and table.size is not None and move > 0 and _on_table(obj, table):
            half = np.asarray(table.size[:2]) / 2.0
            low = table.position[:2] - half - obj.position[:2]
            high = table.position[:2] + half - obj.position[:2]
            shift[:2] = np.clip(rng.uniform(-move, move, 2), low, high)
            said.append(f"{obj.name} moved by ({shift[0]:+.2f}, {shift[1]:+.2f}) m")
        elif obj.kind == "person" and move > 0:  # standing elsewhere beside the table
            shift[:2] = rng.uniform(-move, move, 2)
            said.append(f"{obj.name} moved by ({shift[0]:+.2f}, {shift[1]:+.2f}) m")
        objects.append(_moved(obj, shift) if shift.any() else obj)
    if rise:
        said.append(f"table {rise:+.3f} m")
    return Scene(objects), rise, ", ".join(said)


def _safety(safety: TaskSafety, rise: float) -> TaskSafety:
    """The tool's box with its floor moved with the table's top."""
    if safety.tool_box is None or rise == 0.0:
        return safety
    lower, upper = safety.tool_box
    return dataclasses.replace(safety, tool_box=((lower[0], lower[1], lower[2] + rise), upper))


def _second(task: Task) -> tuple[FeatureSpec, ...]:
    """The task's features with a second learned one (SECOND_FEATURE) added, learned from 0."""
    owner, name = SECOND_FEATURE.get(task.task_feature, _DEFAULT_SECOND)
    if name in task.feature_names:
        raise InvalidParameterError(f"second: task '{task.name}' already has feature '{name}'")
    spec = load_task(owner).features[load_task(owner).feature_names.index(name)]
    return (*task.features, dataclasses.replace(spec, initial=0.0))


def _draw(
    task: Task, rng: np.random.Generator, move: float, table_height: float, pose: float, second: bool
) -> Task:
    robot = _robot(task.robot)
    scene, rise, said = _scene(task, rng, move, table_height)
    start, goal = (
        np.clip(q + rng.uniform(-pose, pose, q.shape), robot.lower_limits, robot.upper_limits)
        if pose > 0
        else q
        for q in (task.start, task.goal)
    )
    if pose > 0:
        said += (", " if said else "") + f"start and goal turned by up to {math.degrees(pose):.0f}°"
    features = _second(task) if second else task.features
    if second:
        said += (", " if said else "") + f"'{features[-1].name}' learned too"
    return dataclasses.replace(
        task,
        start=start,
        goal=goal,
        scene=scene,
        features=features,
        safety=_safety(task.safety, rise),
        source=f"{task.source} (varied)",
        title=said or "unchanged",
    )


def _check(task: Task) -> None:
    """Raises PhriError unless the study could run `task`: both plans clear, converged and feasible,
    start and goal within the limits and the tool's box."""
    from phri.sim.episode import Planner  # the study's own checks; phri.sim is heavier than phri.tasks

    robot = _robot(task.robot)
    planner = Planner(task, robot)
    _, info = planner.optimizer.solve(task.vector("initial"), task.start, task.goal)
    planner.check(info, "initial")
    box = task.safety.tool_box
    if box is not None and robot.hand_frame is not None:
        for what, q in (("start", task.start), ("goal", task.goal)):
            p = robot.frame_pose(robot.hand_frame, q)[:3, 3]
            if np.any(p < np.asarray(box[0])) or np.any(p > np.asarray(box[1])):
                raise PlanningError(f"{task.source}: the {what} puts the tool outside [safety] tool_box")


def vary(
    task: Task,
    rng: np.random.Generator,
    *,
    move: float = 0.15,
    table_height: float = 0.03,
    pose: float = math.radians(5.0),
    second: bool = False,
    attempts: int = 50,
) -> Task:
    """A feasible variation of `task` drawn with `rng`: each object lying on the table moved by up
    to `move` [m] in x and y (uniform, staying on the table) and each person by as much, the table
    and what is on it raised or lowered by up to `table_height` [m] (the tool box's floor with it),
    each joint of the start and the goal turned by up to `pose` [rad]; with `second`, a second
    learned feature (SECOND_FEATURE).
    The returned task keeps the name; its ``title`` says what changed and its ``source`` that it
    was varied. Raises PlanningError if none of `attempts` draws is feasible."""
    for name, value in (("move", move), ("table_height", table_height), ("pose", pose)):
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not (math.isfinite(value) and value >= 0)
        ):
            raise InvalidParameterError(f"{name} must be a finite number >= 0, got {value!r}")
    if isinstance(attempts, bool) or not isinstance(attempts, int) or attempts < 1:
        raise InvalidParameterError(f"attempts must be an integer >= 1, got {attempts!r}")
    if not isinstance(rng, np.random.Generator):
        raise InvalidParameterError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    last: PhriError | None = None
    for _ in range(attempts):
        varied = _draw(task, rng, float(move), float(table_height), float(pose), second)
        try:
            _check(varied)
        except PhriError as e:
            last = e
            continue
        return varied
    raise PlanningError(
        f"vary: none of {attempts} variations of task '{task.name}' is feasible; the last: {last}"
    )
