"""Issue 31: task variations (phri.tasks.vary) and the simulated person off the paper's exact scenes.

The study-sized checks run benches/variations.py's own code on 3 variations per task with 3 people
(the bench runs 30 with 6); see docs/participant.md, "Scenes the person was checked on"."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import load_bench

import phri
from phri.config import TABLE
from phri.exceptions import InvalidParameterError, PlanningError
from phri.sim import EpisodeConfig, World
from phri.sim.episode import Planner, simulate_episode
from phri.sim.participant import Participant, ParticipantParams, default_population
from phri.sim.participant.perception import MATCH_WINDOW, REFERENCE_SPACING, TaskView
from phri.tasks import SECOND_FEATURE, vary

JACO2 = phri.Robot.jaco2()
#: The bench's seed for the tests (any fixed one: the checks must hold for it).
SEED = 2026


def _moved(task: phri.Task, name: str, shift: tuple[float, float, float]) -> phri.Task:
    objects = []
    for obj in task.scene.objects:
        args, kwargs = obj.__getnewargs_ex__()
        if obj.name == name:
            args = (*args[:2], np.asarray(obj.position) + shift, *args[3:])
        objects.append(phri.SceneObject(*args, **kwargs))
    return dataclasses.replace(task, scene=phri.Scene(objects))


# -- vary ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["coffee", "table", "laptop", "human"])
def test_a_variation_is_feasible_reproducible_and_says_what_changed(name: str) -> None:
    task = phri.load_task(name)
    varied = vary(task, np.random.default_rng(5))
    again = vary(task, np.random.default_rng(5))
    np.testing.assert_array_equal(varied.start, again.start)
    np.testing.assert_array_equal(varied.goal, again.goal)
    assert varied.title == again.title and "laptop moved by" in varied.title
    assert varied.name == task.name and varied.source.endswith("(varied)")
    # Within the limits, turned by at most 5° per joint.
    for q, q0 in ((varied.start, task.start), (varied.goal, task.goal)):
        assert np.all(np.abs(q - q0) <= math.radians(5.0) + 1e-12)
        JACO2.check_limits(q)
    # The laptop is moved on the table, the table and the laptop by the same height, the tool's
    # box floor with the table's top.
    table, table0 = varied.scene.get(TABLE), task.scene.get(TABLE)
    laptop, laptop0 = varied.scene.get("laptop"), task.scene.get("laptop")
    rise = table.position[2] - table0.position[2]
    assert abs(rise) <= 0.03 and laptop.position[2] - laptop0.position[2] == pytest.approx(rise)
    assert 0 < np.abs(laptop.position[:2] - laptop0.position[:2]).max() <= 0.15
    assert np.all(np.abs(laptop.position[:2] - table.position[:2]) <= np.asarray(table.size[:2]) / 2)
    assert varied.safety.tool_box[0][2] == pytest.approx(task.safety.tool_box[0][2] + rise)
    person, person0 = varied.scene.get("person"), task.scene.get("person")
    assert 0 < np.abs(person.position[:2] - person0.position[:2]).max() <= 0.15
    assert person.position[2] == person0.position[2] and "person moved by" in varied.title
    # Feasible: the study's planner accepts it (it raises otherwise) and the initial plan is clear.
    planner = Planner(varied, JACO2)
    info = planner.optimizer.solve(varied.vector("initial"), varied.start, varied.goal)[1]
    planner.check(info, "initial")


def test_a_second_learned_feature_is_learned_from_zero() -> None:
    for name in ("table", "coffee", "laptop"):
        task = phri.load_task(name)
        both = vary(task, np.random.default_rng(1), second=True)
        owner, feature = SECOND_FEATURE.get(task.task_feature, ("coffee", "coffee"))
        added = both.features[-1]
        assert added.name == feature and added.learned and added.initial == 0.0
        source = phri.load_task(owner)
        assert added.true == source.vector("true")[source.feature_names.index(feature)]
        assert f"'{feature}' learned too" in both.title
        assert both.task_feature == task.task_feature
    with pytest.raises(InvalidParameterError, match="second: task 'table' already has feature 'coffee'"):
        both = vary(phri.load_task("table"), np.random.default_rng(1), second=True)
        vary(both, np.random.default_rng(1), second=True)


def test_bad_variation_settings_are_clear_errors() -> None:
    task = phri.load_task("table")
    rng = np.random.default_rng(0)
    for kwargs, pattern in [
        ({"move": -0.1}, "move must be a finite number >= 0, got -0.1"),
        ({"table_height": math.nan}, "table_height must be a finite number >= 0"),
        ({"pose": "5"}, "pose must be a finite number >= 0, got '5'"),
        ({"attempts": 0}, "attempts must be an integer >= 1, got 0"),
    ]:
        with pytest.raises(InvalidParameterError, match=pattern):
            vary(task, rng, **kwargs)
    with pytest.raises(InvalidParameterError, match="rng must be a numpy.random.Generator, got int"):
        vary(task, 3)  # type: ignore[arg-type]
    # A task no variation of which is feasible (2 s for the table task's motion is too fast).
    infeasible = r"none of 2 variations of task 'table' is feasible; the last: .*duration"
    with pytest.raises(PlanningError, match=infeasible):
        vary(dataclasses.replace(task, duration=2.0), rng, attempts=2)


def test_unvaried_is_the_task_itself() -> None:
    task = phri.load_task("laptop")
    same = vary(task, np.random.default_rng(0), move=0.0, table_height=0.0, pose=0.0)
    assert same.title == "unchanged"
    np.testing.assert_array_equal(same.start, task.start)
    positions = [o.position.tolist() for o in task.scene.objects]
    assert [o.position.tolist() for o in same.scene.objects] == positions


# -- the person off the paper's scene -------------------------------------------------------------------


def test_the_person_compares_with_the_demonstration_near_the_clock() -> None:
    task = phri.load_task("laptop")
    planner = Planner(task, JACO2)
    view = TaskView(task, JACO2, planner.desired)
    assert view.window == MATCH_WINDOW
    for t in (2.0, 6.0, 11.0):
        k = int(round(t / task.duration * (len(planner.desired) - 1)))
        view.look(planner.desired[k], t)
        assert abs(view.progress * REFERENCE_SPACING - t) <= MATCH_WINDOW + 1e-9
    with pytest.raises(InvalidParameterError, match="window must be a time > 0 s, got 0"):
        TaskView(task, JACO2, planner.desired, window=0)


def test_with_the_laptop_moved_the_person_pushes_the_cup_out_of_its_circle() -> None:
    """The issue's report: the laptop moved by (+0.2, +0.15) m. The initial plan passes through the
    circle, at twice the desired cost; the person used to match the demonstration by place, up to 6 s
    ahead of the clock, where it too is inside the circle, and never pushed."""
    task = _moved(phri.load_task("laptop"), "laptop", (0.2, 0.15, 0.0))
    person = default_population().draw(0, 1)
    with World() as world:
        planner = Planner(task, world)
        initial = planner.optimizer.solve(task.vector("initial"), task.start, task.goal)[0]
        assert planner.features.phi(initial)[task.task_index] > 2 * planner.desired_cost
        result, error = simulate_episode(
            task, world, person, EpisodeConfig(strategy="impedance"), seed=1, planner=planner
        )
    assert error is None and result.effort > 10.0 and result.interaction_time > 0.5


def test_one_at_a_time_the_person_corrects_the_most_visible_error_first_then_the_next() -> None:
    """HRI 2018's people: with the cup both high and tilted, only the more visible error of the two
    (in units of the person's tolerances; here the tilt) is corrected, until it looks fixed."""
    table, coffee = phri.load_task("table"), phri.load_task("coffee")
    both = dataclasses.replace(table, features=(*table.features, coffee.features[1]))
    desired = Planner(table, JACO2).desired
    k = 10
    t = k * table.duration / (len(desired) - 1)
    q = desired[k]
    upright = JACO2.frame_pose(JACO2.feature_frame, q)[:3, 0]
    axis = np.cross(upright, [0.0, 0.0, 1.0])
    axis /= np.linalg.norm(axis)
    jac = JACO2.jacobian(JACO2.feature_frame, q)
    params = ParticipantParams(delay=0.0, noise=0.0, off_axis=0.0, rise_time=0.0, rate=100.0)
    params = dataclasses.replace(params, tolerance=0.02, tilt_tolerance=0.1)
    wrong = q + np.linalg.pinv(jac) @ np.concatenate([[0.0, 0.0, 0.03], -0.5 * axis])
    high_only = q + np.linalg.pinv(jac) @ np.array([0.0, 0.0, 0.05, 0.0, 0.0, 0.0])

    def person(one_at_a_time: bool) -> Participant:
        p = Participant(params, both, JACO2, desired, np.random.default_rng(0), one_at_a_time=one_at_a_time)
        p.wrench(t, q)
        return p

    together, focused = person(False), person(True)
    height, tilt = together.errors(together.view.look(wrong, t))
    assert tilt > height > 1.0  # both visible, the tilt more
    force, torque = together.wrench(t + 0.01, wrong)
    assert force[2] < -1.0 and torque @ axis > 0.1  # both at once
    force, torque = focused.wrench(t + 0.01, wrong)
    assert torque @ axis > 0.1 and abs(force[2]) < 0.5 * abs(together.wrench(t + 0.01, wrong)[0][2])
    assert focused.focus == 1  # the tilt, the second watched feature
    # Once the tilt looks fixed, the height is next.
    for j in range(2, 40):
        force, torque = focused.wrench(t + 0.01 * j, high_only)
    assert focused.focus == 0 and force[2] < -1.0
    with pytest.raises(InvalidParameterError, match="one_at_a_time must be True or False"):
        Participant(params, both, JACO2, desired, np.random.default_rng(0), one_at_a_time=1)  # type: ignore[arg-type]
    with pytest.raises(InvalidParameterError, match="one_at_a_time"):
        EpisodeConfig(one_at_a_time="yes")  # type: ignore[arg-type]


# -- the bench's checks, small ----------------------------------------------------------------------------


@pytest.mark.slow
def test_off_the_paper_scenes_people_push_where_the_robot_is_wrong_and_learning_needs_less() -> None:
    """3 variations of each of the four tasks, 3 people each, seeded: where the initial plan costs
    more than the desired behaviour by over 20 %, the person pushes in at least 80 % of impedance
    episodes; learning needs less effort and less interaction time than impedance on average in at
    least 90 % of the variations with a push; no episode ends in an error other than a safety stop."""
    bench = load_bench("variations")
    outcomes = bench.run(SEED, bench.TASKS, 3, 3)
    checks = bench.check(outcomes)
    table = bench.report(outcomes, bench.TASKS)
    assert checks.wrong_episodes >= 18, table  # the variations are mostly wrong, as the paper's tasks
    assert checks.push_share >= bench.PUSH_SHARE, table
    assert checks.better_share >= bench.BETTER_SHARE, table
    # A safety stop is the safety layer doing its job (docs/participant.md: a blend into a new plan
    # that the arm overshoots); any other end of an episode is a bug.
    assert checks.failures == 0, table


@pytest.mark.slow
def test_with_a_second_learned_feature_learning_needs_less_effort_and_ends_closer() -> None:
    """Two-feature variations (the table's height learned too on the cup task, the cup's tilt on the
    human task): on average over 6 people, in each of 2 variations of each. Not on the table task
    with the tilt added, where learning needs more effort than impedance in 20 of 30 variations
    (docs/participant.md, "Scenes the person was checked on").

    Six people per variation, as the bench's studies have: with three, one variation's mean is one
    person's luck (when the person's off-axis push stopped taking its direction from rounding, the
    draws changed and a variation came out 8 % the other way; over 30 variations of each task the
    bench's rate went from 93 % to 96 %, `benches/variations.py --seed 11 --second`)."""
    bench = load_bench("variations")
    tasks = ("coffee", "human")
    outcomes = bench.run(SEED, tasks, 2, 6, second=True)
    table = bench.report(outcomes, tasks)
    for o in outcomes:
        assert np.mean(o.effort["learning"]) < np.mean(o.effort["impedance"]), table
        assert o.learning_closer, table
    assert bench.check(outcomes).failures == 0, table
