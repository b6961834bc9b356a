"""Task files: the shipped study tasks and errors that name the file, the key and the expectation."""

from __future__ import annotations

import math

import numpy as np
import pytest

import phri
from phri.exceptions import ConfigError, UnknownNameError


def test_the_four_study_tasks_ship_with_their_numbers() -> None:
    assert phri.task_names() == ["coffee", "human", "laptop", "table"]
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
        ("waypoints = 31", "waypoints = 2", r"key 'waypoints' must be an integer >= 3"),
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
    with pytest.raises(UnknownNameError, match="known: coffee, human, laptop, table"):
        phri.load_task("kitchen")
    with pytest.raises(ConfigError, match="not found"):
        phri.load_task("/does/not/exist.toml")


def test_degrees_become_radians() -> None:
    task = phri.load_task("human")
    assert math.isclose(task.start[0], math.radians(210.8))
