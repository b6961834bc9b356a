"""Features the person cares about and the robot does not model (a task file's [unmodelled.<name>]
tables): the person's desired behaviour and corrections include them; the robot never sees them."""

from importlib import resources

import numpy as np
import pytest
from conftest import load_bench

import phri
from phri import load_task
from phri.exceptions import ConfigError
from phri.sim import World
from phri.sim.episode import EpisodeConfig, Planner, simulate_episode
from phri.sim.participant import ParticipantParams

#: The bench's unmodelled laptop keep-out (a task file's [unmodelled.laptop] table).
LAPTOP = load_bench("misspecified").UNMODELLED_LAPTOP


def table_with(tmp_path, extra: str, *, table_true: float = 0.0):
    """The table task, its height already right (true = initial) unless `table_true`, plus `extra`."""
    text = (resources.files("phri.tasks") / "table.toml").read_text(encoding="utf-8")
    text = text.replace('name = "table"', 'name = "table_laptop"')
    text = text.replace(
        "[features.table]\ninitial = 0.0\ntrue = 1.0", f"[features.table]\ninitial = 0.0\ntrue = {table_true}"
    )
    path = tmp_path / "table_laptop.toml"
    # "TOP ..." goes before the first table, as a top-level key.
    path.write_text(extra[4:] + text if extra.startswith("TOP ") else text + extra, encoding="utf-8")
    return load_task(path)


def test_the_robot_does_not_see_unmodelled_features(tmp_path):
    task = table_with(tmp_path, LAPTOP)
    assert task.feature_names == ["efficiency", "table"]
    (spec,) = task.unmodelled
    assert (spec.name, spec.initial, spec.true, spec.learned) == ("laptop", 0.0, 10.0, True)
    seen = task.seen_by_person()
    assert seen.feature_names == ["efficiency", "table", "laptop"] and seen.unmodelled == ()
    table = load_task("table")
    assert table.seen_by_person() is table
    planner = Planner(task, phri.Robot.jaco2())
    assert len(planner.features) == 2
    # The desired behaviour keeps the cup out of the laptop's circle; the robot's plan does not.
    person = seen.feature_set(phri.Robot.jaco2())
    laptop = seen.feature_names.index("laptop")
    initial, _ = planner.optimizer.solve(task.vector("initial"), task.start, task.goal)
    assert person.phi(planner.desired)[laptop] < 0.5 * person.phi(initial)[laptop]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("[unmodelled.table]\ntrue = 1.0\n", "models a feature of that name"),
        (LAPTOP.replace("true = 10.0", "true = 10.0\nstep = 1.0"), "only 'true'"),
        (LAPTOP.replace("true = 10.0", "true = 0.0"), "unmodelled.laptop.true"),
        (LAPTOP.replace('keep_out = "laptop"', 'keep_out = "vase"'), "unmodelled.laptop"),
        ("TOP unmodelled = 3\n", "key 'unmodelled' must be a table of feature tables"),
    ],
)
def test_bad_unmodelled_tables_are_named(tmp_path, extra, message):
    with pytest.raises(ConfigError, match=message):
        table_with(tmp_path, extra)


def test_the_person_pushes_for_an_unmodelled_reason(tmp_path):
    """With the height right, only the laptop is wrong: the person pushes, and the paper's rule reads
    those pushes as evidence about the height."""
    task = table_with(tmp_path, LAPTOP)
    pushes = {}
    with World() as world:
        for name, t in (("unmodelled", task), ("height right", table_with(tmp_path, ""))):
            result, error = simulate_episode(t, world, ParticipantParams(), EpisodeConfig(), seed=3)
            assert error is None
            pushes[name] = result.log_arrays["interaction_t"].size
            if name == "unmodelled":
                beta = result.log_arrays["interaction_beta"]
                assert result.final_weights.shape == (2,)
    assert pushes["height right"] == 0, "nothing the person cares about is wrong"
    assert pushes["unmodelled"] > 5
    assert np.nanmedian(beta) < phri.BETA_THRESHOLD * 3
