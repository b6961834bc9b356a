"""A study folder stands on its own (issue 16 #21, #23): it keeps copies of the task files it was
started with and reads them there, so it is resumed and reported from anywhere and after the
original files moved; and it opens nothing outside itself, whatever study.json or results.csv say."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from importlib.resources import files
from pathlib import Path

import pytest

from phri.study import (
    ResultStore,
    StudyConfig,
    StudyConfigError,
    StudyFileError,
    StudyMismatchError,
    load_results,
    run_study,
)
from phri.study.report import write_report


@pytest.fixture
def elsewhere(tmp_path: Path) -> Iterator[Path]:
    """A working directory of its own for the test (the study must not depend on it)."""
    cwd = Path.cwd()
    work = tmp_path / "work"
    work.mkdir()
    os.chdir(work)
    try:
        yield work
    finally:
        os.chdir(cwd)


def _own_task(folder: Path, name: str = "my_laptop") -> Path:
    """The shipped laptop task under another name, as a user's task file."""
    text = (files("phri") / "tasks" / "laptop.toml").read_text()
    lines = [f'name = "{name}"' if line.startswith("name ") else line for line in text.splitlines()]
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def _config(task: str) -> StudyConfig:
    return StudyConfig(
        participants=1, attempts=1, seed=3, tasks=(task,), familiarization=None, duration=8.0, waypoints=10
    )


def test_task_files_are_copied_and_the_study_resumes_and_reports_from_anywhere(
    elsewhere: Path, tmp_path: Path
) -> None:
    task = _own_task(elsewhere / "mine")
    run_dir = tmp_path / "study"
    run_study(run_dir, _config("mine/my_laptop.toml"), backend="serial", progress=False, max_episodes=1)
    manifest = json.loads((run_dir / "study.json").read_text())
    assert manifest["config"]["tasks"] == ["tasks/my_laptop.toml"]
    assert (run_dir / "tasks" / "my_laptop.toml").read_bytes() == task.read_bytes()

    # The original file gone, another working directory: the folder's copy is read.
    task.unlink()
    other = tmp_path / "other"
    other.mkdir()
    os.chdir(other)
    run = run_study(run_dir, backend="serial", progress=False)
    assert run.complete and run.ran == 1
    assert len(load_results(run_dir)) == 2
    report = write_report(run_dir)
    assert "my_laptop" in report.read_text()

    # Resuming with the study's options as first given still reads as the same study...
    os.chdir(elsewhere)
    _own_task(elsewhere / "mine")
    with ResultStore.open(run_dir, _config("mine/my_laptop.toml")) as store:
        assert store.complete
    # ... and a task file edited since is refused, naming it.
    edited = _own_task(elsewhere / "mine")
    edited.write_text(edited.read_text().replace("title = ", 'title = "edited" #'))
    with pytest.raises(StudyMismatchError, match=r"the task file\(s\) \['my_laptop'\] changed"):
        ResultStore.open(run_dir, _config("mine/my_laptop.toml"))


@pytest.mark.parametrize("named", ["/etc/hostname", "../outside.toml", "tasks/../../outside.toml", "tasks/"])
def test_study_json_naming_a_file_outside_the_study_folder_is_refused(tmp_path: Path, named: str) -> None:
    run_dir = tmp_path / "study"
    _own_task(tmp_path, "outside")
    with ResultStore.open(
        run_dir, StudyConfig(participants=1, attempts=1, tasks=("coffee",), familiarization=None)
    ):
        pass
    path = run_dir / "study.json"
    manifest = json.loads(path.read_text())
    manifest["config"]["tasks"] = [named]
    path.write_text(json.dumps(manifest))
    for open_it in (
        lambda: ResultStore.open(run_dir),
        lambda: write_report(run_dir),
        lambda: load_results(run_dir),
    ):
        with pytest.raises(StudyConfigError, match=r"must be a file in the study folder's tasks/"):
            open_it()


@pytest.mark.parametrize(
    "log", ["/etc/hostname", "../x.npz", "logs/../../x.npz", "logs/p02_learning_coffee_a1.npz"]
)
def test_results_naming_a_log_outside_its_own_are_refused(tmp_path: Path, log: str) -> None:
    run_dir = tmp_path / "study"
    config = StudyConfig(
        participants=1, attempts=1, tasks=("coffee",), familiarization=None, duration=8.0, waypoints=10
    )
    run_study(run_dir, config, backend="serial", progress=False, max_episodes=1)
    path = run_dir / "results.csv"
    header, row = path.read_text().splitlines()[:2]
    own = next(c for c in row.split(",") if c.startswith("logs/"))
    path.write_text(f"{header}\n{row.replace(own, log)}\n")
    for open_it in (
        lambda: ResultStore.open(run_dir),
        lambda: write_report(run_dir),
        lambda: load_results(run_dir),
    ):
        with pytest.raises(StudyFileError, match=rf"the log of episode .* must be '{own}' \(or none\)"):
            open_it()
