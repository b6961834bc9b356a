"""The study protocol, its folder (manifest, incremental table, resume, refusal of a foreign study),
the backends' agreement, the statistics against hand computations, the report and the CLI."""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

import phri.config
from phri.exceptions import ConfigError, InvalidParameterError, PhriError
from phri.sim.participant import default_population, load_population
from phri.study import (
    COLUMNS,
    ResultStore,
    StudyConfig,
    StudyConfigError,
    StudyFileError,
    StudyLockedError,
    StudyMismatchError,
    analysis,
    episode_seed,
    load_results,
    participant_params,
    run_study,
    schedule,
    strategy_order,
)
from phri.study import run as run_module
from phri.study.calibrate import (
    DEFAULT_FREE,
    CalibrationError,
    CalibrationSettings,
    calibrate,
    write_population,
)
from phri.study.cli import main as cli
from phri.study.parallel import THREAD_ENV, ProcessBackend, default_workers, make_backend
from phri.study.report import _pooled_form, write_report
from phri.study.targets import TargetsError, read_targets

#: A study small enough for CI: 2 participants × 2 strategies × 2 tasks × 2 attempts = 16 episodes of 8 s
#: (the shortest duration, with some margin, at which the human task's goal is reachable within the
#: planner's joint speeds: shorter is a PlanningError).
TINY = StudyConfig(participants=2, attempts=2, seed=7, tasks=("human", "laptop"), duration=8.0, waypoints=10)
#: TINY as `phri study` options.
TINY_ARGS = ["--participants", "2", "--attempts", "2", "--seed", "7", "--tasks", "human,laptop",
             "--duration", "8", "--waypoints", "10"]  # fmt: skip


def table_without_wall_time(run_dir: Path) -> pd.DataFrame:
    return load_results(run_dir).drop(columns="wall_time")


def snapshot(folder: Path) -> dict[str, str]:
    """Every file under `folder` and the SHA-256 of its bytes."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def copy_study(reference: Path, to: Path) -> Path:
    """A copy of the reference study folder that a test may change."""
    shutil.copytree(reference, to, ignore=shutil.ignore_patterns("report*"))
    return to


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """TINY run serially in one go: the table every other way of running it must reproduce."""
    run_dir = tmp_path_factory.mktemp("study") / "reference"
    run = run_study(run_dir, TINY, backend="serial", progress=False)
    assert run.complete and run.ran == TINY.episodes == 16
    return run_dir


# -- protocol ---------------------------------------------------------------------------------------


def test_default_study_is_the_papers() -> None:
    config = StudyConfig()
    specs = schedule(config)
    assert config.episodes == len(specs) == 160  # 10 × 2 strategies × 4 tasks × 2 attempts
    assert [s.index for s in specs] == list(range(160))
    first = specs[: 2 * 4 * 2]
    assert {s.participant for s in first} == {1}
    assert [s.task for s in first[:8]] == [
        "human",
        "human",
        "coffee",
        "coffee",
        "table",
        "table",
        "laptop",
        "laptop",
    ]
    assert [s.attempt for s in first[:4]] == [1, 2, 1, 2]
    # Counterbalanced: half the participants start with each strategy.
    starts = [strategy_order(config, p)[0] for p in range(1, 11)]
    assert starts.count("impedance") == starts.count("learning") == 5
    for s in specs:
        assert strategy_order(config, s.participant)[s.order - 1] == s.strategy
    assert len({s.key for s in specs}) == 160
    assert len({s.seed for s in specs}) == 160


def test_seeds_depend_on_what_not_when() -> None:
    """An episode's seed depends on (study seed, participant, strategy, task, attempt) only."""
    full = {s.key: s.seed for s in schedule(StudyConfig(participants=3))}
    fewer = {s.key: s.seed for s in schedule(StudyConfig(participants=2, tasks=("laptop", "human")))}
    assert all(full[k] == v for k, v in fewer.items())
    assert episode_seed(0, 1, "learning", "laptop", 1) != episode_seed(1, 1, "learning", "laptop", 1)
    assert episode_seed(0, 1, "learning", "laptop", 1) != episode_seed(0, 1, "learning", "laptop", 2)
    assert 0 <= max(full.values()) < 2**63
    assert participant_params(3, 2) == participant_params(3, 2)
    assert participant_params(3, 2) != participant_params(3, 1)


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"participants": 0}, "participants"),
        ({"participants": -3}, "participants"),
        ({"participants": 2.5}, "participants"),
        ({"participants": 10**6}, r"participants must be an integer in \[1, 10000\]"),
        ({"participants": 10**400}, "participants"),
        ({"attempts": 0}, "attempts"),
        ({"attempts": 101}, "attempts"),
        ({"seed": -1}, "seed"),
        ({"strategies": ("learning", "telepathy")}, "strategies"),
        ({"tasks": ()}, "tasks"),
        ({"tasks": ("human", "human")}, "tasks"),
        ({"familiarization": "coffee", "tasks": ("human", "laptop")}, "familiarization"),
        ({"duration": 0.0}, "duration"),
        ({"waypoints": 2}, "waypoints"),
        ({"knots": 2}, "knots"),
        ({"knots": -1}, "knots"),
        ({"knots": 3.5}, "knots"),
        ({"rule": "most"}, "rule"),
        ({"sample_rate": 0.0}, "sample_rate"),
        ({"sample_rate": "fast"}, "sample_rate"),
        ({"sensor_noise": -1.0}, "sensor_noise"),
    ],
)
def test_bad_study_parameters_are_clear_errors(kwargs: dict, key: str) -> None:
    with pytest.raises(StudyConfigError, match=key) as info:
        StudyConfig(**kwargs)
    assert isinstance(info.value, ConfigError | InvalidParameterError)


def test_knots_override_every_tasks_and_put_every_knot_on_a_waypoint() -> None:
    assert {t.knots for t in StudyConfig(knots=4).load_tasks().values()} == {4}
    assert {t.knots for t in StudyConfig(knots=0).load_tasks().values()} == {0}
    assert StudyConfig(knots=5).to_dict()["knots"] == 5
    every = "3, 4, 6, 7, 11, 16"
    for knots, waypoints, fitting in ((40, None, every), (5, None, every), (11, 11, "3, 6")):
        message = rf"knots of task 'human' must be .*\({fitting}\), got {knots}"
        with pytest.raises(StudyConfigError, match=message):
            StudyConfig(knots=knots, waypoints=waypoints).load_tasks()


def test_an_edited_study_json_beyond_the_limits_is_refused_at_once(reference: Path, tmp_path: Path) -> None:
    """Issue 16 #13: study.json edited to 10⁷ participants is refused before any scheduling."""
    run_dir = copy_study(reference, tmp_path / "s")
    manifest = json.loads((run_dir / "study.json").read_text())
    manifest["config"]["participants"] = 10**7
    (run_dir / "study.json").write_text(json.dumps(manifest))
    began = time.monotonic()
    with pytest.raises(PhriError, match="participants"):
        run_study(run_dir, progress=False)
    assert time.monotonic() - began < 10


def test_unknown_task_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(StudyConfigError, match="nosuchtask"):
        StudyConfig(tasks=("nosuchtask",), familiarization=None)
    config = StudyConfig(tasks=(str(tmp_path / "missing.toml"),), familiarization=None)
    with pytest.raises(StudyConfigError, match="missing.toml"):
        run_study(tmp_path / "s", config, backend="serial", progress=False)
    assert not (tmp_path / "s").exists()


def test_study_toml(tmp_path: Path) -> None:
    good = tmp_path / "study.toml"
    good.write_text('participants = 4\nseed = 3\ntasks = ["human", "table"]\nduration = 3.0\n')
    assert StudyConfig.from_toml(good) == StudyConfig(
        participants=4, seed=3, tasks=("human", "table"), duration=3.0
    )
    for text, match in [
        ("participants = 0\n", "participants must be an integer in \\[1, 10000\\]"),
        ("participants = 'ten'\n", "participants"),
        ("participant = 10\n", "unknown key"),
        ("participants = [\n", "not valid TOML"),
        ("tasks = 'human'\n", "tasks"),
    ]:
        bad = tmp_path / "bad.toml"
        bad.write_text(text)
        with pytest.raises(StudyConfigError, match=match) as info:
            StudyConfig.from_toml(bad)
        assert str(bad) in str(info.value)
    with pytest.raises(StudyConfigError, match="cannot read"):
        StudyConfig.from_toml(tmp_path / "missing.toml")


def test_config_round_trips_through_a_dict() -> None:
    assert StudyConfig.from_dict(TINY.to_dict()) == TINY
    assert StudyConfig.from_dict(json.loads(json.dumps(TINY.to_dict()))) == TINY


# -- the study folder -------------------------------------------------------------------------------


def test_folder_holds_table_logs_and_manifest(reference: Path) -> None:
    for name in ("study.json", "participants.csv", "results.csv", "results.parquet"):
        assert (reference / name).is_file(), name
    manifest = json.loads((reference / "study.json").read_text())
    assert StudyConfig.from_dict(manifest["config"]) == TINY
    table = load_results(reference)
    assert list(table.columns) == list(COLUMNS)
    assert len(table) == 16 and (table["status"] == "ok").all()
    assert table[["participant", "strategy", "task", "attempt"]].drop_duplicates().shape[0] == 16
    assert [tuple(r) for r in table[["participant", "strategy", "task", "attempt"]].to_numpy()] == [
        s.key for s in schedule(TINY)
    ]
    # CSV and Parquet hold the same table; the CSV is sorted in session order once complete.
    parquet = pd.read_parquet(reference / "results.parquet")
    pd.testing.assert_frame_equal(parquet, table, check_dtype=False)
    assert pd.read_csv(reference / "results.csv")["seed"].tolist() == table["seed"].tolist()
    weights = [json.loads(w) for w in table["final_weights"]]
    assert all(set(w) == {"efficiency", t} for w, t in zip(weights, table["task"], strict=True))
    assert np.allclose([w[t] for w, t in zip(weights, table["task"], strict=True)], table["final_weight"])
    # Every episode has its log with the time series and the desired plan.
    for log in table["log"]:
        with np.load(reference / log) as data:
            assert data["q"].shape[1] == 7 and data["desired"].shape == (TINY.waypoints, 7)
            assert len(data["t"]) == pytest.approx(801, abs=1)  # 8 s at 100 Hz
    assert (table["effort"] >= 0).all() and (table["interaction_time"] >= 0).all()


def test_rerunning_a_complete_study_changes_nothing(reference: Path) -> None:
    before = snapshot(reference)
    run = run_study(reference, progress=False)
    assert run.complete and run.ran == 0 and run.resumed == 16
    after = snapshot(reference)
    assert {k: v for k, v in after.items() if k != "results.parquet"} == {
        k: v for k, v in before.items() if k != "results.parquet"
    }


def test_resume_after_max_episodes_gives_the_same_table(reference: Path, tmp_path: Path) -> None:
    run_dir = tmp_path / "study"
    first = run_study(run_dir, TINY, backend="serial", progress=False, max_episodes=5)
    assert (first.ran, first.complete) == (5, False)
    assert len(load_results(run_dir)) == 5
    second = run_study(run_dir, TINY, backend="serial", progress=False)
    assert (second.resumed, second.ran, second.complete) == (5, 11, True)
    pd.testing.assert_frame_equal(table_without_wall_time(run_dir), table_without_wall_time(reference))


def test_interrupted_study_loses_nothing_and_resumes(reference: Path, tmp_path: Path) -> None:
    run_dir = tmp_path / "study"
    seen: list[dict] = []

    def stop_after_three(spec, row):  # noqa: ANN001
        seen.append(row)
        if len(seen) == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_study(run_dir, TINY, backend="serial", progress=False, on_episode=stop_after_three)
    kept = load_results(run_dir)
    assert len(kept) == 3
    assert len(pd.read_parquet(run_dir / "results.parquet")) == 3
    # A kill in the middle of writing a row, inside a multi-byte character (issue 16 #8: a task
    # named "café"), and a log whose row was never written.
    with open(run_dir / "results.csv", "ab") as f:
        f.write(b"2,learning,1,caf" + "é".encode()[:1])
    assert len(load_results(run_dir)) == 3
    pending = [
        s
        for s in schedule(TINY)
        if s.key not in {tuple(r) for r in kept[["participant", "strategy", "task", "attempt"]].to_numpy()}
    ]
    orphan = run_dir / "logs" / pending[0].log_name()
    orphan.write_bytes(b"half a log")
    # Resuming without repeating the study's parameters: the folder's own study.
    run = run_study(run_dir, progress=False)
    assert (run.resumed, run.ran, run.complete) == (3, 13, True)
    pd.testing.assert_frame_equal(table_without_wall_time(run_dir), table_without_wall_time(reference))
    assert not list((run_dir / "logs").glob("*.partial"))


def test_a_different_study_is_refused_and_nothing_changes(reference: Path) -> None:
    before = snapshot(reference)
    for other in (
        StudyConfig(**{**TINY.to_dict(), "seed": 8, "tasks": TINY.tasks}),
        StudyConfig(**{**TINY.to_dict(), "participants": 3, "tasks": TINY.tasks}),
        StudyConfig(),
    ):
        with pytest.raises(StudyMismatchError, match="another study") as info:
            run_study(reference, other, backend="serial", progress=False)
        assert isinstance(info.value, ConfigError)
    with pytest.raises(StudyMismatchError, match=r"seed: 7 here, 8 asked"):
        ResultStore.open(reference, StudyConfig(**{**TINY.to_dict(), "seed": 8, "tasks": TINY.tasks}))
    assert snapshot(reference) == before


def test_broken_or_foreign_folders_are_clear_errors(reference: Path, tmp_path: Path) -> None:
    # A broken manifest: an error naming it; nothing is touched.
    broken = tmp_path / "broken"
    broken.mkdir()
    for name in ("results.csv", "participants.csv"):
        (broken / name).write_bytes((reference / name).read_bytes())
    for text, match in [
        ("{not json", "study.json: not a readable study manifest"),
        ('{"format": "other"}', "not a phri study manifest"),
        (json.dumps({"format": "phri-study", "version": 2, "config": {"participants": 0}}), "participants"),
        (json.dumps({"format": "phri-study", "version": 99, "config": {}}), "version"),
    ]:
        (broken / "study.json").write_text(text)
        before = snapshot(broken)
        with pytest.raises(StudyFileError, match=match):
            run_study(broken, TINY, backend="serial", progress=False)
        with pytest.raises(StudyFileError):
            load_results(broken)
        assert snapshot(broken) == before
    # Results without a manifest: refused, untouched.
    (broken / "study.json").unlink()
    before = snapshot(broken)
    with pytest.raises(StudyFileError, match="no study.json"):
        run_study(broken, TINY, backend="serial", progress=False)
    assert snapshot(broken) == before
    # A malformed table: the line is named; nothing is touched.
    damaged = tmp_path / "damaged"
    damaged.mkdir()
    for name in ("study.json", "participants.csv"):
        (damaged / name).write_bytes((reference / name).read_bytes())
    lines = (reference / "results.csv").read_text().splitlines(keepends=True)
    (damaged / "results.csv").write_text(
        "".join(lines[:3]) + lines[3].replace(",ok,", ",ok,x,") + "".join(lines[4:])
    )
    before = snapshot(damaged)
    with pytest.raises(StudyFileError, match=r"results.csv: line 4"):
        run_study(damaged, TINY, backend="serial", progress=False)
    assert snapshot(damaged) == before
    # A file where the folder should be.
    file = tmp_path / "file"
    file.write_text("x")
    with pytest.raises(StudyFileError, match="not a folder"):
        run_study(file, TINY, backend="serial", progress=False)


def test_one_writer_at_a_time(tmp_path: Path) -> None:
    with ResultStore.open(tmp_path / "study", TINY):
        with pytest.raises(StudyLockedError, match="another process"):
            ResultStore.open(tmp_path / "study", TINY)
    with ResultStore.open(tmp_path / "study", TINY) as store:
        assert len(store.pending()) == 16


def test_the_folder_is_locked_before_its_manifest_is_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 16 #2: a second writer that read study.json before taking the lock could take a study
    finished meanwhile for a new one and reset it; the lock now comes first."""
    import fcntl
    import os

    from phri.study import results

    held: list[bool] = []
    read = results.read_manifest

    def probing(run_dir: Path):  # noqa: ANN202
        fd = os.open(run_dir, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            held.append(False)
        except BlockingIOError:
            held.append(True)
        finally:
            os.close(fd)
        return read(run_dir)

    monkeypatch.setattr(results, "read_manifest", probing)
    with ResultStore.open(tmp_path / "study", TINY):
        pass
    with ResultStore.open(tmp_path / "study", TINY):
        pass
    assert held == [True, True]

    # A refused open of a new folder leaves nothing behind.
    def unreadable(self: StudyConfig) -> None:
        raise StudyFileError("a task file vanished")

    monkeypatch.setattr(StudyConfig, "load_tasks", unreadable)
    with pytest.raises(StudyFileError, match="vanished"):
        ResultStore.open(tmp_path / "new", TINY)
    assert not (tmp_path / "new").exists()


def test_bad_execution_arguments(tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="backend"):
        run_study(tmp_path / "a", TINY, backend="threads", progress=False)
    assert not (tmp_path / "a").exists()
    with pytest.raises(InvalidParameterError, match="max_episodes"):
        run_study(tmp_path / "b", TINY, max_episodes=-1, progress=False)


@pytest.mark.parametrize("workers", [0, -1, 1.5])
def test_workers_must_be_at_least_one(tmp_path: Path, capsys: pytest.CaptureFixture[str], workers) -> None:  # noqa: ANN001
    """0 is not "all CPUs" (leave --workers out for that), and nothing is created for a bad value."""
    for backend in ("serial", "process"):
        with pytest.raises(InvalidParameterError, match=rf"workers must be an integer >= 1.*got {workers}"):
            run_study(tmp_path / "s", TINY, backend=backend, workers=workers, progress=False)
        assert not (tmp_path / "s").exists()
    if isinstance(workers, int):
        assert (
            cli(["study", str(tmp_path / "s"), *TINY_ARGS, "--workers", str(workers), "--no-progress"]) == 2
        )
        assert f"workers must be an integer >= 1 (leave it out for the CPUs available), got {workers}" in (
            capsys.readouterr().err
        )
        assert not (tmp_path / "s").exists()
        with pytest.raises(InvalidParameterError, match="workers must be >= 1"):
            ProcessBackend(TINY, workers=workers)


def test_another_phri_version_is_refused_unless_allowed(
    reference: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from phri import __version__

    run_dir = copy_study(reference, tmp_path / "s")
    manifest = json.loads((run_dir / "study.json").read_text())
    (run_dir / "study.json").write_text(json.dumps({**manifest, "phri_version": "0.0.1"}, indent=2) + "\n")
    before = snapshot(run_dir)
    with pytest.raises(
        StudyMismatchError, match=rf"started with phri 0\.0\.1, this is phri {__version__}"
    ) as info:
        run_study(run_dir, progress=False, backend="serial")
    assert "new folder" in str(info.value) and "allow-version-change" in str(info.value)
    assert cli(["study", str(run_dir), "--no-progress", "--backend", "serial"]) == 2
    assert "started with phri 0.0.1" in capsys.readouterr().err
    assert snapshot(run_dir) == before
    # Allowed: resumes, and the manifest keeps both versions (the report says the table is mixed).
    assert cli(["study", str(run_dir), "--no-progress", "--backend", "serial", "--allow-version-change"]) == 0
    assert "16 of 16 episodes" in capsys.readouterr().out
    resumed = json.loads((run_dir / "study.json").read_text())
    assert resumed["phri_version"] == "0.0.1" and resumed["resumed_with"] == [__version__]
    assert {k: v for k, v in resumed.items() if k != "resumed_with"} == {**manifest, "phri_version": "0.0.1"}
    # The same version as the folder's: no flag needed, nothing rewritten.
    manifest_bytes = (run_dir / "study.json").read_bytes()
    assert run_study(reference, progress=False, backend="serial").complete
    run_study(run_dir, progress=False, backend="serial", allow_version_change=True)
    assert (run_dir / "study.json").read_bytes() == manifest_bytes


def test_questionnaire_between_strategies(tmp_path: Path) -> None:
    calls: list[tuple[int, str]] = []
    run_study(
        tmp_path / "s",
        TINY,
        backend="serial",
        progress=False,
        between_strategies=lambda p, s: calls.append((p, s)),
    )
    assert calls == [(1, "impedance"), (1, "learning"), (2, "learning"), (2, "impedance")]
    with pytest.raises(InvalidParameterError, match="serial"):
        run_study(tmp_path / "t", TINY, backend="process", between_strategies=lambda p, s: None)


def test_ask_on_resume_asks_lost_questionnaires(tmp_path: Path) -> None:
    """A block finished in an earlier call whose questionnaire was never answered is asked first."""
    run_dir = tmp_path / "s"
    run_study(run_dir, TINY, backend="serial", progress=False, max_episodes=6)  # (1, impedance) done
    calls: list[tuple[int, str]] = []
    answered = {(2, "learning")}
    kwargs = {"backend": "serial", "progress": False, "answered": lambda p, s: (p, s) in answered}
    run_study(run_dir, between_strategies=lambda p, s: calls.append((p, s)), max_episodes=0, **kwargs)
    assert calls == [(1, "impedance")]
    answered.add((1, "impedance"))
    run_study(run_dir, between_strategies=lambda p, s: calls.append((p, s)), **kwargs)
    # (1, learning) and (2, impedance) finished now; (2, learning) was answered.
    assert calls == [(1, "impedance"), (1, "learning"), (2, "impedance")]
    # Once complete, every block without answers is asked again, in session order.
    calls.clear()
    run_study(run_dir, between_strategies=lambda p, s: calls.append((p, s)), **kwargs)
    assert calls == [(1, "learning"), (2, "impedance")]


def test_cli_ask_on_resume(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from phri.study import questionnaire as q

    run_dir = tmp_path / "s"
    asked: list[tuple[int, str]] = []

    def ask(participant: int, strategy: str) -> dict[str, int]:
        asked.append((participant, strategy))
        return {c: 4 for c in q.ITEM_COLUMNS}

    monkeypatch.setattr(q, "ask", ask)
    assert (
        cli(
            ["study", str(run_dir), *TINY_ARGS, "--backend", "serial", "--no-progress", "--max-episodes", "5"]
        )
        == 0
    )
    assert asked == [] and not (run_dir / "questionnaire.csv").exists()
    # Interrupted during the questionnaire of (1, impedance): resuming with --ask asks it.
    assert cli(["study", str(run_dir), "--ask", "--no-progress", "--max-episodes", "0"]) == 0
    assert asked == [(1, "impedance")]
    assert q.read_responses(run_dir / "questionnaire.csv")[["participant", "strategy"]].values.tolist() == [
        [1, "impedance"]
    ]
    assert cli(["study", str(run_dir), "--ask", "--no-progress", "--max-episodes", "0"]) == 0
    assert asked == [(1, "impedance")]  # answered now: not asked again


# -- backends ---------------------------------------------------------------------------------------


@pytest.mark.slow
def test_process_pool_gives_the_same_table(reference: Path, tmp_path: Path) -> None:
    run = run_study(tmp_path / "pool", TINY, backend="process", workers=2, progress=False)
    assert run.complete and run.workers == 2
    pd.testing.assert_frame_equal(
        table_without_wall_time(tmp_path / "pool"), table_without_wall_time(reference)
    )
    # Interrupted pool run, resumed serially: still the same table.
    run_study(tmp_path / "mixed", TINY, backend="process", workers=2, progress=False, max_episodes=7)
    run_study(tmp_path / "mixed", progress=False, backend="serial")
    pd.testing.assert_frame_equal(
        table_without_wall_time(tmp_path / "mixed"), table_without_wall_time(reference)
    )


def _process_table() -> dict[int, tuple[int, str, str]]:
    """pid -> (parent pid, state, start time) of every process, from /proc."""
    table = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue  # ended meanwhile
            fields = stat[stat.rindex(")") + 2 :].split()
            table[int(entry.name)] = (int(fields[1]), fields[0], fields[19])
    return table


def _descendants(pid: int) -> dict[int, str]:
    """pid -> start time of every process below `pid`."""
    table, found, todo = _process_table(), {}, [pid]
    while todo:
        parent = todo.pop()
        for child, (ppid, _, start) in table.items():
            if ppid == parent and child not in found:
                found[child] = start
                todo.append(child)
    return found


def _alive(processes: dict[int, str]) -> list[int]:
    """Those of `processes` still running (a zombie or a reused pid does not count)."""
    table = _process_table()
    return [p for p, start in processes.items() if p in table and table[p][1] != "Z" and table[p][2] == start]


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the workers through /proc (Linux)")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_killed_study_leaves_no_workers_and_resumes(reference: Path, tmp_path: Path, sig: int) -> None:
    """`phri study --backend process` killed after its first row: its pool workers end within seconds
    (SIGKILL: they notice their parent is gone; SIGTERM: the study shuts its pool down as after
    Ctrl-C), and resuming gives the table of an uninterrupted run."""
    run_dir = tmp_path / "s"
    command = [sys.executable, "-m", "phri.study", "study", str(run_dir), *TINY_ARGS,
               "--backend", "process", "--workers", "2", "--no-progress"]  # fmt: skip
    with open(tmp_path / "stderr.txt", "w") as stderr:
        study = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=stderr)
    workers: dict[int, str] = {}
    try:
        results, deadline = run_dir / "results.csv", time.monotonic() + 120
        while not (results.exists() and results.read_text().count("\n") >= 2):
            assert study.poll() is None, (tmp_path / "stderr.txt").read_text()
            assert time.monotonic() < deadline, "no episode recorded in 120 s"
            time.sleep(0.02)
        workers = _descendants(study.pid)
        assert len(workers) >= 2  # the pool's two workers (and multiprocessing's resource tracker)
        os.kill(study.pid, sig)
        code = study.wait(timeout=60)
        deadline = time.monotonic() + 10
        while _alive(workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _alive(workers) == [], "pool workers outlived the killed study"
    finally:
        study.kill()
        for pid in _alive(workers):
            os.kill(pid, signal.SIGKILL)
    if sig == signal.SIGTERM:
        assert code == 143
        assert "terminated (SIGTERM); every finished episode is kept" in (tmp_path / "stderr.txt").read_text()
    else:
        assert code == -signal.SIGKILL
    assert 1 <= len(load_results(run_dir)) < 16
    run = run_study(run_dir, progress=False, backend="serial")
    assert run.complete and run.resumed >= 1
    pd.testing.assert_frame_equal(table_without_wall_time(run_dir), table_without_wall_time(reference))


@pytest.mark.slow
def test_pool_workers_are_single_threaded() -> None:
    backend = ProcessBackend(TINY, workers=2)
    try:
        envs = backend.worker_environments()
    finally:
        backend.close()
    assert envs == [THREAD_ENV, THREAD_ENV]


def study_with_a_task_file(folder: Path) -> tuple[StudyConfig, Path]:
    """TINY with its laptop task read from a copy of the shipped file in `folder` (same rows as TINY's)."""
    task_file = folder / "laptop.toml"
    shutil.copyfile(Path(phri.config.__file__).parent / "tasks" / "laptop.toml", task_file)
    return dataclasses.replace(TINY, tasks=("human", str(task_file))), task_file


def reference_rows(reference: Path, keys: list[tuple[int, str, str, int]]) -> pd.DataFrame:
    """The reference table's rows of the episodes `keys`, in that order, without wall time."""
    table = table_without_wall_time(reference)
    rows = table.set_index(["participant", "strategy", "task", "attempt"]).loc[keys].reset_index()
    return rows[table.columns]


@pytest.mark.slow
def test_pool_workers_run_the_drivers_tasks_and_read_no_task_file(
    reference: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The driver loads and checks the task files; the workers get the Task objects. A task file gone
    once the study started (as on a cluster node without it) changes nothing: the pool, whose workers
    start with the first episode, after the file is deleted, gives the reference rows."""
    config, task_file = study_with_a_task_file(tmp_path)

    def make_backend_then_delete_the_task_file(*args, **kwargs):
        backend = make_backend(*args, **kwargs)
        task_file.unlink()  # loaded by the driver; no worker has started yet
        return backend

    monkeypatch.setattr(run_module, "make_backend", make_backend_then_delete_the_task_file)
    run = run_study(tmp_path / "s", config, backend="process", workers=2, progress=False, max_episodes=4)
    assert not task_file.exists() and run.ran == 4 and run.workers == 2
    study_with_a_task_file(tmp_path)  # back, for load_results (its schedule reads the task names)
    table = table_without_wall_time(tmp_path / "s")
    keys = list(table[["participant", "strategy", "task", "attempt"]].itertuples(index=False, name=None))
    assert {k[2] for k in keys} == {"human", "laptop"}
    pd.testing.assert_frame_equal(table, reference_rows(reference, keys))


def test_backends_check_the_tasks_they_are_given() -> None:
    tasks = TINY.load_tasks()
    for bad in ({"human": "human.toml"}, {"coffee": tasks["human"]}, list(tasks.values())):
        for backend in ("serial", "process"):
            with pytest.raises(InvalidParameterError, match=r"^tasks must map each task name to its "):
                make_backend(backend, TINY, tasks=bad)  # type: ignore[arg-type]


@pytest.mark.slow
def test_ray_gives_the_same_table(reference: Path, tmp_path: Path) -> None:
    ray = pytest.importorskip(
        "ray", reason="Ray is not installed (optional extra phri[ray]); backend 'ray' untested"
    )
    from phri.study.parallel import RayBackend

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        run = run_study(tmp_path / "ray", TINY, backend="ray", workers=2, progress=False)
        assert run.complete and run.workers == 2
        pd.testing.assert_frame_equal(
            table_without_wall_time(tmp_path / "ray"), table_without_wall_time(reference)
        )
        backend = RayBackend(TINY, workers=1)
        try:
            assert backend.worker_environments() == [THREAD_ENV]
        finally:
            backend.close()
    finally:
        ray.shutdown()


@pytest.mark.slow
def test_ray_actors_default_to_the_cluster_cpus_and_read_no_task_file(
    reference: Path, tmp_path: Path
) -> None:
    """Without `workers`, one actor per CPU of the Ray instance (on a cluster: every node's, not this
    machine's); the actors run the driver's Task objects, so they need no task file."""
    ray = pytest.importorskip(
        "ray", reason="Ray is not installed (optional extra phri[ray]); backend 'ray' untested"
    )
    from phri.study.parallel import RayBackend

    cpus = default_workers() + 1  # a "cluster" with more CPUs than this machine gives this process
    ray.init(num_cpus=cpus, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        config, task_file = study_with_a_task_file(tmp_path)
        tasks, specs = config.load_tasks(), schedule(config)
        task_file.unlink()
        backend = RayBackend(config, tasks=tasks)
        try:
            assert backend.workers == len(backend.actors) == int(ray.cluster_resources()["CPU"]) == cpus
            assert backend.worker_environments() == [THREAD_ENV] * cpus  # every actor started
            laptop = [s for s in specs if s.task == "laptop"][:2]
            outcomes = sorted(backend.run(laptop), key=lambda o: o.spec)
        finally:
            backend.close()
    finally:
        ray.shutdown()
    rows = pd.DataFrame([o.row for o in outcomes]).drop(columns="wall_time")
    expected = reference_rows(reference, [s.key for s in laptop])
    assert rows.to_dict("records") == expected.to_dict("records")


# -- statistics against hand computations -------------------------------------------------------------


def _two_by_two(rng: np.random.Generator, n: int) -> pd.DataFrame:
    rows = []
    for p in range(1, n + 1):
        person = rng.normal(0, 2)
        for s, bump in (("impedance", 3.0), ("learning", 0.0)):
            for a in (1, 2):
                rows.append(
                    {
                        "participant": p,
                        "strategy": s,
                        "attempt": a,
                        "y": person + bump + 0.5 * a + rng.normal(),
                    }
                )
    return pd.DataFrame(rows)


def test_factorial_anova_matches_hand_computation() -> None:
    data = _two_by_two(np.random.default_rng(1), 6)
    out = analysis.factorial_anova(data, "y").set_index("effect")
    y, grand = data["y"].to_numpy(), data["y"].mean()
    cell = data.groupby(["strategy", "attempt"])["y"].transform("mean").to_numpy()
    ss_error, df_error = float(((y - cell) ** 2).sum()), len(y) - 4
    for effect, factor in (("strategy", "strategy"), ("attempt", "attempt")):
        level = data.groupby(factor)["y"].transform("mean").to_numpy()
        ss = float(((level - grand) ** 2).sum())
        row = out.loc[effect]
        assert (row["df1"], row["df2"]) == (1, df_error)
        assert row["F"] == pytest.approx(ss / (ss_error / df_error), rel=1e-9)
        assert row["partial_eta_sq"] == pytest.approx(ss / (ss + ss_error), rel=1e-9)
        assert row["p"] == pytest.approx(stats.f.sf(row["F"], 1, df_error), rel=1e-9)
    # The paper's form: 120 observations, F(1, 116).
    big = _two_by_two(np.random.default_rng(2), 30)
    assert set(analysis.factorial_anova(big, "y")["df2"]) == {116.0}


def test_rm_anova_matches_paired_t_tests() -> None:
    """With two levels per factor, each effect's F is the square of a one-sample t on the right contrast."""
    data = _two_by_two(np.random.default_rng(3), 8)
    out = analysis.rm_anova(data, "y").set_index("effect")
    wide = data.pivot_table(index="participant", columns=["strategy", "attempt"], values="y")
    imp1, imp2 = wide[("impedance", 1)], wide[("impedance", 2)]
    lrn1, lrn2 = wide[("learning", 1)], wide[("learning", 2)]
    contrasts = {
        "strategy": (imp1 + imp2) / 2 - (lrn1 + lrn2) / 2,
        "attempt": (imp1 + lrn1) / 2 - (imp2 + lrn2) / 2,
        "strategy:attempt": imp1 - imp2 - lrn1 + lrn2,
    }
    for effect, c in contrasts.items():
        t = stats.ttest_1samp(c, 0.0)
        row = out.loc[effect]
        assert (row["df1"], row["df2"]) == (1, 7)
        assert row["F"] == pytest.approx(t.statistic**2, rel=1e-9)
        assert row["p"] == pytest.approx(t.pvalue, rel=1e-7)
        assert row["partial_eta_sq"] == pytest.approx(row["F"] / (row["F"] + 7), rel=1e-12)
    # One factor: F(1, n − 1) = paired t².
    one = analysis.rm_anova(data, "y", within=("strategy",)).iloc[0]
    means = data.groupby(["participant", "strategy"])["y"].mean().unstack()
    t = stats.ttest_rel(means["impedance"], means["learning"])
    assert one["F"] == pytest.approx(t.statistic**2, rel=1e-9)


def test_rm_anova_leaves_out_incomplete_participants_and_degenerate_cases() -> None:
    data = _two_by_two(np.random.default_rng(4), 5)
    dropped = data[~((data["participant"] == 5) & (data["strategy"] == "learning"))]
    assert set(analysis.rm_anova(dropped, "y")["df2"]) == {3.0}
    assert analysis.rm_anova(data[data["participant"] == 1], "y").empty
    assert analysis.rm_anova(data[data["strategy"] == "learning"], "y", within=("strategy",)).empty


def _no_error_variance(noise: float = 0.0, seed: int = 0) -> pd.DataFrame:
    """Two participants whose value is the same in every cell but for a learning bump (+ `noise`):
    the repeated-measures error terms have no variance."""
    rng = np.random.default_rng(seed)
    rows = []
    for p, base in ((1, 12.3), (2, 7.1)):
        for s in ("impedance", "learning"):
            for a in (1, 2):
                y = base + (0.7 if s == "learning" else 0.0) + noise * rng.normal()
                rows.append({"participant": p, "strategy": s, "attempt": a, "task": "laptop", "y": y})
    return pd.DataFrame(rows)


def test_a_test_without_error_variance_is_not_estimable() -> None:
    """statsmodels gives such a table F(1, 1) = −2e29, inf and −0.16; phri reports no number."""
    from statsmodels.stats.anova import AnovaRM

    data = _no_error_variance()
    with np.errstate(all="ignore"):  # statsmodels divides by zero
        raw = AnovaRM(data, "y", "participant", within=["strategy", "attempt"]).fit().anova_table
    assert not (np.isfinite(raw["F Value"]) & (raw["F Value"] >= 0)).all()  # what it would print
    rm = analysis.rm_anova(data, "y")
    assert list(rm["estimable"]) == [False] * 3
    assert rm[["F", "p", "partial_eta_sq"]].isna().all().all()
    assert list(rm["df2"]) == [1.0] * 3  # the degrees of freedom stay: they say why
    # Rounding-level noise (1e-13 of the values) is no variance either: F would be absurdly large.
    assert not analysis.rm_anova(_no_error_variance(1e-13), "y")["estimable"].any()
    # Real noise is a real test.
    real = analysis.rm_anova(_no_error_variance(1e-3), "y")
    assert real["estimable"].all() and np.isfinite(real["F"]).all()
    # The pooled ANOVA: y fixed by strategy alone leaves no residual.
    exact = data.assign(y=np.where(data["strategy"] == "learning", 3.0, 1.0))
    pooled = analysis.factorial_anova(exact, "y")
    assert not pooled["estimable"].any() and pooled["F"].isna().all()
    assert analysis.factorial_anova(_two_by_two(np.random.default_rng(1), 6), "y")["estimable"].all()
    # The report writes "not estimable", never a number, and no asterisk goes into a figure.
    from phri.study import figures
    from phri.study.report import _anova_md

    text = _anova_md(rm)
    assert text.count("F(1, 1): not estimable") == 3 and "e+" not in text and "nan" not in text.lower()
    assert "error term has no variance" in text
    tests = rm.assign(task="laptop", measure="effort", p=1e-20)  # a p that would get an asterisk
    assert np.isnan(figures._star_p(tests, "laptop", "effort"))
    assert figures._star_p(tests.assign(estimable=True), "laptop", "effort") == 1e-20


def test_the_latex_tables_escape_text_and_symbols() -> None:
    from phri.study import latex

    assert latex.escape("partial η² ± 5 % of |cost − desired| & a_b < .0001") == (
        r"partial $\eta$\textsuperscript{2} $\pm$ 5 \% of \textbar{}cost $-$ desired\textbar{} \& a\_b "
        r"\textless{} .0001"
    )
    text = latex.table(["a", "b"], [["1", "x_y"]])
    assert text.splitlines() == [
        r"\begin{tabular}{ll}", r"\toprule", r"a & b \\", r"\midrule", r"1 & x\_y \\", r"\bottomrule",
        r"\end{tabular}",
    ]  # fmt: skip


def test_the_report_states_the_studys_sample_rate() -> None:
    from phri.study.report import _introduction

    config = dataclasses.replace(TINY, sample_rate=20.0)
    raw = pd.DataFrame({"status": ["ok"] * 3})
    text = "\n".join(_introduction(Path("s"), config, {}, raw))
    assert "sampled at 20 Hz" in text and "1/20 Hz = 0.05 s" in text and "10 Hz" not in text


def test_rm_anova_averages_only_tasks_present_in_every_cell() -> None:
    """A participant without task B under one strategy: B (much harder) is left out of all of that
    participant's cells, so it does not pass for a strategy effect."""
    rng = np.random.default_rng(6)
    rows = []
    for p in range(1, 7):
        for s in ("impedance", "learning"):
            for task, offset in (("A", 0.0), ("B", 50.0)):
                for a in (1, 2):
                    y = offset + (1.0 if s == "impedance" else 0.0) + rng.normal()
                    rows.append({"participant": p, "strategy": s, "task": task, "attempt": a, "y": y})
    data = pd.DataFrame(rows)
    gap = data[~((data["participant"] == 1) & (data["strategy"] == "learning") & (data["task"] == "B"))]
    kept, dropped = analysis.matched_tasks(gap)
    assert dropped.values.tolist() == [[1, "B"]]
    assert len(kept) == len(gap) - 2 and not ((kept["participant"] == 1) & (kept["task"] == "B")).any()
    out = analysis.rm_anova(gap, "y").set_index("effect")
    by_hand = analysis.rm_anova(kept, "y").set_index("effect")
    pd.testing.assert_frame_equal(out, by_hand)
    assert out.loc["strategy", "df2"] == 5  # participant 1 stays in, on task A
    # Averaging whatever tasks exist would make participant 1's impedance 25 units worse.
    from statsmodels.stats.anova import AnovaRM

    naive = gap.groupby(["participant", "strategy", "attempt"])["y"].mean().reset_index()
    naive_f = AnovaRM(naive, "y", "participant", within=["strategy", "attempt"]).fit().anova_table
    assert naive_f.loc["strategy", "F Value"] != pytest.approx(out.loc["strategy", "F"], rel=1e-3)
    # Without a task column (the questionnaire's scores) nothing changes.
    plain = _two_by_two(np.random.default_rng(3), 8)
    assert analysis.matched_tasks(plain)[0] is plain


def test_descriptives_and_cost_error(reference: Path) -> None:
    data = analysis.prepare(load_results(reference))
    assert np.allclose(data["cost_error"], (data["cost"] - data["desired_cost"]).abs())
    desc = analysis.descriptives(data)
    assert list(desc["task"].drop_duplicates()) == ["human", "laptop"]
    sub = data[(data["task"] == "laptop") & (data["strategy"] == "learning")]["effort"]
    row = desc[(desc["task"] == "laptop") & (desc["strategy"] == "learning")].iloc[0]
    assert row["n"] == 4
    assert row["effort_mean"] == pytest.approx(sub.mean()) and row["effort_sd"] == pytest.approx(
        sub.std(ddof=1)
    )


# -- report and CLI ---------------------------------------------------------------------------------------


def _png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


@pytest.mark.slow
def test_report(reference: Path, tmp_path: Path) -> None:
    answers = tmp_path / "answers.csv"
    rng = np.random.default_rng(0)
    lines = ["participant,strategy," + ",".join(f"q{i}" for i in range(1, 11))]
    for p in (1, 2, 3):
        for s in ("impedance", "learning"):
            lines.append(f"{p},{s}," + ",".join(str(int(x)) for x in rng.integers(1, 8, 10)))
    answers.write_text("\n".join(lines) + "\n")
    before = snapshot(reference)
    path = write_report(reference, tmp_path / "report", questionnaire=answers)
    assert snapshot(reference) == before  # the study folder is only read
    text = path.read_text()
    needles = ("Per task and strategy", "F(1, ", "AnovaRM", "partial η²", "|cost − desired cost|", "Cronbach")
    for needle in (*needles, "fig4_effort_time.png", "fig5_cost.png", "fig5_paths.png", "Table 1"):
        assert needle in text, needle
    for name in ("fig4_effort_time", "fig5_cost", "fig5_paths"):
        width, height = _png_size(tmp_path / "report" / f"{name}.png")
        assert width > 600 and height > 300
        assert (tmp_path / "report" / f"{name}.pdf").read_bytes()[:5] == b"%PDF-"
    for name in ("descriptives", "anova_pooled", "anova_rm", "anova_by_task", "table1"):
        assert (tmp_path / "report" / f"{name}.csv").is_file()
        tex = (tmp_path / "report" / f"{name}.tex").read_text()
        assert tex.startswith("\\begin{tabular}") and tex.isascii(), name
        assert f"`{name}.tex`" in text
    # The same report as HTML beside it, linking each episode to its replay page.
    page = (tmp_path / "report" / "report.html").read_text()
    assert "<table>" in page and '<img alt="' in page and 'src="fig4_effort_time.png"' in page
    links = re.findall(r'href="(replays/[^"]+[.]html)"', page)
    assert len(links) == len(load_results(reference)) and len(set(links)) == len(links)
    assert all((tmp_path / "report" / link).is_file() for link in links)
    replay = (tmp_path / "report" / links[0]).read_text()
    assert '<script src="viewer/viewer.js"></script>' in replay
    assert (tmp_path / "report" / "replays" / "viewer" / "three.min.js").is_file()
    assert "## Episode replays" in text and "(replays/" in text
    # TINY's rate and log rate, not fixed numbers; its 2 participants are too few to test.
    assert "sampled at 10 Hz" in text and "from the episode logs (100 Hz)" in text
    assert "## Warnings" in text and "The study has 2 participant(s), fewer than 3: too few to test" in text
    rm = pd.read_csv(tmp_path / "report" / "anova_rm.csv")
    assert set(rm["df2"]) == {1.0} and "estimable" in rm
    pooled = pd.read_csv(tmp_path / "report" / "anova_pooled.csv")
    # TINY's experimental trials: 2 participants × 1 task × 2 strategies × 2 attempts = 8 → F(1, 4),
    # and the report says so rather than claiming the paper's form.
    assert set(pooled["df2"]) == {4.0}
    assert "Here it has the form F(1, 4)" in text and "paper's F(1, 116) form" not in text
    with pytest.raises(StudyFileError, match="no study.json"):
        write_report(tmp_path / "nothing")


def test_pooled_form_names_what_was_computed() -> None:
    paper = analysis.factorial_anova(_two_by_two(np.random.default_rng(2), 30), "y")
    assert "Here it has the paper's F(1, 116) form" in _pooled_form(paper)
    small = _pooled_form(analysis.factorial_anova(_two_by_two(np.random.default_rng(2), 6), "y"))
    assert "Here it has the form F(1, 20);" in small and "paper's F(1, 116) form" not in small
    three = _two_by_two(np.random.default_rng(2), 6)
    three = pd.concat([three, three[three["attempt"] == 1].assign(attempt=3)], ignore_index=True)
    assert "F(1, 30) and F(2, 30)" in _pooled_form(analysis.factorial_anova(three, "y"))
    assert "No F test" in _pooled_form(pd.DataFrame(columns=analysis.ANOVA_COLUMNS))


@pytest.mark.slow
def test_report_never_overwrites_and_fails_cleanly(
    reference: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from phri.study.errors import QuestionnaireError

    run_dir = copy_study(reference, tmp_path / "s")
    first = write_report(run_dir)
    assert first == run_dir / "report" / "report.md"
    first.write_text("my notes on the report\n")  # edited by hand
    kept = snapshot(run_dir / "report")
    assert cli(["report", str(run_dir), "--participant", "2"]) == 0
    out = capsys.readouterr().out
    assert f"{run_dir / 'report'} exists and was left as it is" in out
    assert f"report: {run_dir / 'report-2' / 'report.md'}" in out
    assert snapshot(run_dir / "report") == kept
    assert "Participant 2, task 'laptop'" in (run_dir / "report-2" / "report.md").read_text()
    assert (run_dir / "report-2").stat().st_mode & 0o777 == (run_dir / "logs").stat().st_mode & 0o777
    # An explicit --out that exists: OUT-2; an empty one is used as it is.
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    assert write_report(run_dir, mine) == tmp_path / "mine-2" / "report.md"
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]
    (tmp_path / "empty").mkdir()
    assert write_report(run_dir, tmp_path / "empty") == tmp_path / "empty" / "report.md"
    # A failing report (a broken questionnaire file, read after the figures are drawn) leaves nothing.
    bad = tmp_path / "bad.csv"
    bad.write_text(
        "participant,strategy," + ",".join(f"q{i}" for i in range(1, 11)) + "\n1,learning" + ",9" * 10
    )
    listing = sorted(p.name for p in run_dir.iterdir())
    with pytest.raises(QuestionnaireError, match="must be 1-7"):
        write_report(run_dir, questionnaire=bad)
    assert sorted(p.name for p in run_dir.iterdir()) == listing
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["s", "mine", "mine-2", "empty", "bad.csv"])


def test_report_survives_damaged_logs_and_refuses_foreign_rows(reference: Path, tmp_path: Path) -> None:
    """Issue 16 #7, #17, #24: a damaged log costs only its figure (named), a missing one is a
    warning, a killed report's staging folder is cleaned up, and duplicated or foreign rows are
    refused as `phri study` refuses them, never counted."""
    run_dir = copy_study(reference, tmp_path / "s")
    table = load_results(run_dir)
    sample = table[(table["participant"] == 1) & (table["task"] == "laptop")]
    (run_dir / sample["log"].iloc[0]).write_bytes(b"PK\x03\x04 truncated")
    gone = table[table["task"] == "human"]["log"].iloc[0]
    (run_dir / gone).unlink()
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    stale = run_dir / f".report.partial-{int(dead.stdout)}-abcd1234"
    stale.mkdir()
    (stale / "report.md").write_text("half")
    md = write_report(run_dir).read_text()
    assert "is damaged" in md and str(sample["log"].iloc[0]) in md
    assert "1 of the 16 recorded episodes have no log" in md and gone in md
    assert "No replay for 1 log:" in md  # the damaged one; the missing one has no row to link
    assert len(list((run_dir / "report" / "replays").glob("*.html"))) == 14
    assert "## Statistics" in md or "ANOVA" in md
    assert not stale.exists()
    # A duplicated row and a foreign one: the report refuses them as a resume would.
    csv_path = run_dir / "results.csv"
    lines = csv_path.read_text().splitlines(keepends=True)
    csv_path.write_text("".join([*lines, lines[1]]))
    with pytest.raises(StudyFileError, match=rf"line {len(lines) + 1}: episode .* is recorded twice"):
        write_report(run_dir)
    csv_path.write_text("".join([*lines, lines[1].replace("1,", "9,", 1)]))
    with pytest.raises(StudyFileError, match=rf"line {len(lines) + 1}: an episode .* not in this study"):
        write_report(run_dir)


def test_report_sample_must_be_in_the_study(
    reference: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run_dir = copy_study(reference, tmp_path / "s")
    before = snapshot(run_dir)
    for kwargs, match in [
        (
            {"participant": 99},
            r"participant \(--participant\) must be one of the study's participants 1-2, got 99",
        ),
        ({"participant": 0}, r"participants 1-2, got 0"),
        (
            {"task": "coffee"},
            r"task \(--task\) must be one of the study's tasks \['human', 'laptop'\], got 'coffee'",
        ),
    ]:
        with pytest.raises(StudyConfigError, match=match):
            write_report(run_dir, **kwargs)
    assert cli(["report", str(run_dir), "--participant", "99"]) == 2
    assert "must be one of the study's participants 1-2, got 99" in capsys.readouterr().err
    assert snapshot(run_dir) == before


@pytest.mark.slow
def test_report_says_which_tasks_and_versions_were_mixed(reference: Path, tmp_path: Path) -> None:
    run_dir = copy_study(reference, tmp_path / "s")
    lines = (run_dir / "results.csv").read_text().splitlines(keepends=True)
    gone = [n for n, line in enumerate(lines) if line.startswith("2,learning,") and ",laptop,2," in line]
    assert len(gone) == 1
    (run_dir / "results.csv").write_text("".join(lines[: gone[0]] + lines[gone[0] + 1 :]))
    manifest = json.loads((run_dir / "study.json").read_text())
    (run_dir / "study.json").write_text(json.dumps({**manifest, "resumed_with": ["9.9.9"]}))
    text = write_report(run_dir).read_text()
    assert "participant 2: 'laptop' (so the participant is left out entirely)" in text
    assert f"started with phri {manifest['phri_version']}, resumed with phri 9.9.9" in text
    complete = write_report(copy_study(reference, tmp_path / "t")).read_text()
    assert "left out for this reason" not in complete and "Mixed versions" not in complete


def test_report_of_a_study_without_episodes(tmp_path: Path) -> None:
    run_study(tmp_path / "s", TINY, backend="serial", progress=False, max_episodes=0)
    text = write_report(tmp_path / "s").read_text()
    assert "0 of 16 recorded" in text and "The study is incomplete" in text
    assert "No completed episodes yet" in text and "Not enough data" in text


def test_cli_errors_are_clear(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli(["study", str(tmp_path / "s"), "--participants", "0", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "phri study: error:" in err and "participants must be an integer in [1, 10000], got 0" in err
    assert not (tmp_path / "s").exists()
    bad = tmp_path / "bad.toml"
    bad.write_text("participants = [")
    assert cli(["study", str(tmp_path / "s"), "--config", str(bad)]) == 2
    assert "not valid TOML" in capsys.readouterr().err
    assert cli(["report", str(tmp_path / "nothing")]) == 2
    assert "no study.json" in capsys.readouterr().err


def test_an_unreachable_ray_cluster_is_a_clear_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import phri.study.run as run

    def unreachable(*args, **kwargs):
        raise ConnectionError("Could not find any running Ray instance.")

    monkeypatch.setattr(run, "make_backend", unreachable)
    args = ["study", str(tmp_path / "s"), "--backend", "ray", "--address", "auto", "--no-progress"]
    assert cli([*args, *TINY_ARGS]) == 2
    err = capsys.readouterr().err
    assert "phri study: error: cannot reach the Ray cluster at --address 'auto'" in err
    assert "Traceback" not in err


@pytest.mark.slow
def test_cli_study_resume_and_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run_dir = str(tmp_path / "s")
    common = ["--participants", "2", "--attempts", "1", "--tasks", "human,laptop", "--duration", "8",
              "--waypoints", "10", "--backend", "serial", "--no-progress"]  # fmt: skip
    assert cli(["study", run_dir, *common, "--max-episodes", "3"]) == 0
    assert "3 of 8 episodes" in capsys.readouterr().out
    # A different study into the same folder: refused.
    assert cli(["study", run_dir, *common, "--seed", "1"]) == 2
    assert "another study" in capsys.readouterr().err
    # No study options: resume the folder's own study.
    assert cli(["study", run_dir, "--no-progress", "--backend", "serial"]) == 0
    assert "8 of 8 episodes" in capsys.readouterr().out
    assert cli(["report", run_dir]) == 0
    assert (tmp_path / "s" / "report" / "report.md").is_file()
    # The design warning also goes to the log (stderr), unless -qq.
    assert "WARNING: " in capsys.readouterr().err
    assert cli(["-qq", "report", run_dir]) == 0
    assert "WARNING" not in capsys.readouterr().err


def test_errors_are_phri_errors() -> None:
    for cls in (StudyConfigError, StudyFileError, StudyMismatchError, StudyLockedError):
        assert issubclass(cls, ConfigError) and issubclass(cls, PhriError) and issubclass(cls, ValueError)


def test_a_failed_episode_hands_back_its_log_so_far(monkeypatch: pytest.MonkeyPatch) -> None:
    """A simulator failure in a worker is a "failed" row naming the log in the study folder, and the
    log so far comes back in memory (the .npz bytes the driver writes)."""
    import io

    from phri.exceptions import SimulationError
    from phri.sim.participant import Participant
    from phri.study.runner import EpisodeRunner

    runner = EpisodeRunner(TINY, TINY.load_tasks())
    try:
        calls, real = {"n": 0}, Participant.wrench

        def failing(self, t, q):  # noqa: ANN001, ANN202
            calls["n"] += 1  # the person looks 50 times a second: 0.2 s in
            if calls["n"] > 10:
                raise SimulationError("the simulator returned a non-finite joint state")
            return real(self, t, q)

        monkeypatch.setattr(Participant, "wrench", failing)
        spec = schedule(TINY)[0]
        outcome = runner.run(spec)
    finally:
        runner.close()
    name = spec.log_name()
    assert outcome.row["status"] == "failed" and outcome.row["log"] == f"logs/{name}"
    assert "non-finite" in outcome.row["error"] and f"(log so far: logs/{name})" in outcome.row["error"]
    with np.load(io.BytesIO(outcome.log)) as log:
        assert 15 <= len(log["t"]) <= 21


def test_a_second_attempt_is_run_by_the_person_with_practice(monkeypatch: pytest.MonkeyPatch) -> None:
    """The runner hands a person's later attempt their practised parameters (for_attempt), the same
    person's otherwise; the simulation itself is replaced (what it would do with them is
    tests/test_participant.py's)."""
    from phri.exceptions import SimulationError
    from phri.study import runner as runner_module

    seen: dict[int, object] = {}

    def record(task, world, person, config, *, seed, planner):  # noqa: ANN001, ANN202
        seen[len(seen) + 1] = person
        raise SimulationError("not simulated")

    monkeypatch.setattr(runner_module, "simulate_episode", record)
    runner = runner_module.EpisodeRunner(TINY, TINY.load_tasks())
    try:
        spec = schedule(TINY)[0]
        for attempt in (1, 2):
            outcome = runner.run(dataclasses.replace(spec, attempt=attempt))
            assert outcome.row["status"] == "failed" and "not simulated" in outcome.row["error"]
    finally:
        runner.close()
    person = participant_params(TINY.seed, spec.participant, TINY.population)
    assert person.practice > 0
    assert seen == {1: person, 2: person.for_attempt(2)}
    assert seen[2].patience < person.patience  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("position = [-0.7929, 0.0, -0.0891]", "position = [-0.7929, 0.01, -0.0891]"),  # laptop moved
        ("size = [0.23, 0.3, 0.025]", "size = [0.23, 0.3, 0.025]\nmargin = 0.05"),
        ("size = [0.23, 0.3, 0.025]", "size = [0.23, 0.3, 0.025]\nrpy = [0.0, 0.0, 1e-9]"),
        ('kind = "person"', 'kind = "furniture"'),
        ("radius = 0.4 ", "radius = 0.41 "),
    ],
)
def test_a_task_files_digest_covers_its_scene_and_features(tmp_path: Path, old: str, new: str) -> None:
    config, task_file = study_with_a_task_file(tmp_path)
    before = config.task_digests()
    text = task_file.read_text()
    assert old in text
    task_file.write_text(text.replace(old, new, 1))
    after = config.task_digests()
    assert after["human"] == before["human"] and after["laptop"] != before["laptop"]


def test_ray_address_where_nothing_answers_is_a_clear_error_at_once() -> None:
    """Issue 16 #12: Ray retries an unreachable address for ever; phri checks it first."""
    from phri.exceptions import ConnectionLostError
    from phri.study.parallel import RayBackend

    began = time.monotonic()
    with pytest.raises(ConnectionLostError, match=r"address '127.0.0.1:1': no Ray cluster answers"):
        RayBackend(TINY, workers=1, address="127.0.0.1:1")
    assert time.monotonic() - began < 30


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS, errno.EACCES])
def test_refused_file_operations_are_one_line_errors(
    reference: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    code: int,
) -> None:
    """Issue 16 #10: disk full, a read-only folder, no permission (injected: CI runs as root) give
    one line naming the problem and exit status 3 from every command, and lose nothing."""
    import phri.atomic

    run_dir = copy_study(reference, tmp_path / "s")
    kept = snapshot(run_dir)

    def refuse(path, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
        raise OSError(code, os.strerror(code), str(path))

    monkeypatch.setattr(phri.atomic, "open", refuse, raising=False)
    fresh = tmp_path / "fresh"
    commands = [
        ["study", str(fresh), *TINY_ARGS, "--backend", "serial", "--no-progress"],
        ["report", str(run_dir)],
        ["questionnaire", str(run_dir), "--import", str(_answers(tmp_path))],
    ]
    for command in commands:
        assert cli(command) == 3, command
        err = capsys.readouterr().err
        assert f"phri {command[0]}: error: {os.strerror(code)}" in err and "Traceback" not in err
    assert {k: v for k, v in snapshot(run_dir).items() if not k.endswith(".lock")} == kept


def _answers(tmp_path: Path) -> Path:
    path = tmp_path / "answers.csv"
    path.write_text(
        "participant,strategy," + ",".join(f"q{i}" for i in range(1, 11)) + "\n1,learning" + ",4" * 10 + "\n"
    )
    return path


# -- the participants: population, reference statistics, calibration -----------------------------------


#: A population unlike the default: weaker and less patient (a file that extends the default).
WEAK = 'extends = "default"\n[parameters.max_force]\ndistribution = "fixed"\nvalue = 3.0\n'


def test_the_study_draws_its_people_from_its_population_and_keeps_it(tmp_path: Path) -> None:
    weak_file = tmp_path / "weak.toml"
    weak_file.write_text(WEAK)
    weak = load_population(weak_file)
    config = StudyConfig(**{**TINY.to_dict(), "tasks": TINY.tasks, "population": weak})
    assert participant_params(7, 1, weak).max_force == 3.0
    assert participant_params(7, 1) == default_population().draw(7, 1) != participant_params(7, 1, weak)
    # The study keeps the population itself (a resumed study draws the same people).
    again = StudyConfig.from_dict(json.loads(json.dumps(config.to_dict())))
    assert again == config and again.population == weak and again != TINY
    study = tmp_path / "study.toml"
    study.write_text('participants = 2\npopulation = "weak.toml"\n')  # relative to the study file
    assert StudyConfig.from_toml(study).population == weak
    assert StudyConfig(population="default").population == default_population()
    with pytest.raises(StudyConfigError, match="study: population must be a population name, a file path"):
        StudyConfig(population=42)  # type: ignore[arg-type]
    study.write_text('participants = 2\npopulation = "nobody.toml"\n')
    with pytest.raises(
        StudyConfigError, match=r"study.toml: key 'population': .*nobody.toml: population file not found"
    ):
        StudyConfig.from_toml(study)


def test_cli_study_population_errors_name_the_file_and_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "people.toml"
    bad.write_text('extends = "default"\n[parameters.delay]\ndistribution = "fixed"\nvalue = -1\n')
    assert cli(["study", str(tmp_path / "s"), "--population", str(bad), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: key 'parameters.delay.value' must keep delay a finite number >= 0 [s]" in err
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("task,strategy,effort\ncoffee,impedance,1\n", None),
        ("task,strategy,force\ncoffee,impedance,1\n", r"line 2: unknown column 'force'"),
        ("task,effort\ncoffee,1\n", r"missing column 'strategy'"),
        ("task,strategy,effort\ncoffee,compliance,1\n", r"line 3, column 'strategy' must be one of"),
        (
            "task,strategy,effort\ncoffee,impedance,-3\n",
            r"line 3, column 'effort' must be a finite number > 0",
        ),
        (
            "task,strategy,effort,effort_sd\ncoffee,impedance,3,-1\n",
            r"column 'effort_sd' must be a finite number > 0",
        ),
        # Zero SDs and F values divided by zero in the calibration's loss (a traceback, not an error).
        (
            "task,strategy,effort,effort_sd\ncoffee,impedance,3,0\n",
            r"line 3, column 'effort_sd' must be a finite number > 0, got 0",
        ),
        (
            "task,strategy,effort,f_effort,df_error\ncoffee,impedance,3,,\ncoffee+table,,,0,116\n",
            r"line 4, column 'f_effort' must be a finite number > 0, got 0",
        ),
        ("task,strategy,effort,interaction_time_sd\ncoffee,impedance,3,1\n", r"an SD without the mean"),
        ("task,strategy,effort\ncoffee,impedance,1\ncoffee,impedance,2\n", r"line 4: a second row"),
        ("task,strategy,effort\ncoffee,impedance,\n", r"line 3: no target for coffee/impedance"),
        ("task,strategy,f_effort\ncoffee+table,,80\n", r"column 'df_error': missing"),
        ("task,strategy,effort\n", r"no task × strategy rows"),
        ("task,strategy,effort\ncoffee,impedance,1,2\n", r"line 3: 4 fields, the header has 3"),
    ],
)
def test_bad_targets_name_the_file_line_and_column(tmp_path: Path, text: str, pattern: str | None) -> None:
    path = tmp_path / "targets.csv"
    path.write_text("# a comment\n" + text)
    if pattern is None:
        assert read_targets(path).tasks == ["coffee"]
        return
    with pytest.raises(TargetsError, match=f"^{path}: .*{pattern}"):
        read_targets(path)


def test_the_shipped_reference_is_the_papers() -> None:
    paper = read_targets("corl2017")
    assert paper.tasks == ["coffee", "table"]  # the laptop task is held out
    means = {(c.task, c.strategy): dict(c.means) for c in paper.cells}
    assert means[("coffee", "impedance")] == {
        "effort": 260.2,
        "interaction_time": 5.37,
        "effort_per_sample": 4.8,
    }
    (pooled,) = paper.pooled
    assert pooled.tasks == ("coffee", "table", "laptop") and dict(pooled.f)["effort"] == 86.29
    assert pooled.partial_eta_sq("effort") == pytest.approx(86.29 / (86.29 + 116))


@pytest.mark.slow
def test_report_compares_the_study_with_a_reference(reference: Path, tmp_path: Path) -> None:
    targets = tmp_path / "pilot.csv"
    targets.write_text(
        "task,strategy,effort,interaction_time,effort_per_sample,interaction_time_sd,f_effort,df_error\n"
        "laptop,impedance,200,4,5,1,,\nlaptop,learning,50,1,5,,,\nlaptop,,,,,,30,4\n"
    )
    path = write_report(reference, tmp_path / "report", reference=targets)
    text = path.read_text()
    assert "## Against the reference" in text and str(targets) in text
    table = pd.read_csv(tmp_path / "report" / "reference.csv")
    assert list(table.columns) == ["task", "strategy", "statistic", "reference", "simulated", "ratio"]
    results = analysis.prepare(load_results(reference))
    imp = results[(results["task"] == "laptop") & (results["strategy"] == "impedance")]
    row = table[(table["strategy"] == "impedance") & (table["statistic"] == "effort")].iloc[0]
    assert row["simulated"] == pytest.approx(imp["effort"].mean())
    assert row["ratio"] == pytest.approx(imp["effort"].mean() / 200)
    assert len(table) == 8  # 3 + 1 SD, 3, and the pooled F
    with pytest.raises(TargetsError, match=r"task\(s\) \['coffee'\] are not among the study's tasks"):
        write_report(reference, tmp_path / "r2", reference=_targets(tmp_path, "coffee"))


def _targets(folder: Path, task: str, effort: float = 100.0) -> Path:
    path = folder / f"{task}.csv"
    path.write_text(
        f"task,strategy,effort,interaction_time\n{task},impedance,{effort},3\n"
        f"{task},learning,{effort / 3},1\n"
    )
    return path


@pytest.mark.slow
def test_a_tiny_calibration(tmp_path: Path) -> None:
    """make test's only calibration: one participant, one short task, three candidates."""
    table = phri.config.load_task("table")
    goal = table.start + (table.goal - table.start) * 3.0 / table.duration
    short = dataclasses.replace(table, duration=3.0, waypoints=7, goal=goal)
    targets = read_targets(_targets(tmp_path, "table", effort=1e5))  # out of reach in 3 s: it misses
    settings = CalibrationSettings(participants=1, budget=3, free=("max_force.median",), tolerance=0.05)
    seen: list[float] = []
    result = calibrate(targets, settings=settings, tasks={"table": short}, progress=False,
                       on_candidate=lambda k, c: seen.append(c.loss))  # fmt: skip
    assert result.evaluations == len(seen) == 3 and result.best.loss == min(seen)
    assert {r["statistic"] for r in result.best.comparison} == {"effort", "interaction_time"}
    assert not result.reached and "MISSED" in result.table()
    lenient = dataclasses.replace(result, tolerance=1e9)  # the same fit, every target met
    assert lenient.reached and "MISSED" not in lenient.table()
    met = load_population(write_population(lenient, tmp_path / "met.toml", command="x"))
    assert "MISSES" not in dict(met.about)["description"]
    with pytest.raises(
        CalibrationError, match=r"cannot reach \d+ of its targets within ±5 %.*nothing written"
    ):
        write_population(result, tmp_path / "p.toml", command="phri calibrate x")
    assert not (tmp_path / "p.toml").exists()
    out = write_population(result, tmp_path / "p.toml", command="phri calibrate x", accept_misses=True)
    written = load_population(out)
    about = dict(written.about)
    assert about["command"] == "phri calibrate x" and about["seed"] == 0 and "MISSES" in about["description"]
    assert written == result.population
    # The values it started from where they differ, so the command reruns without its --population.
    assert written.calibration_start() == result.start.population and written.calibration_start().about == ()
    assert (about["start"] == "") == (result.population == result.start.population)
    assert all(line.startswith("max_force.median = ") for line in about["start"].splitlines())
    assert result.initial == phri.sim.participant.default_population()
    with pytest.raises(FileExistsError):
        write_population(result, out, command="again", accept_misses=True)


def test_the_recorded_calibration_command_reruns_the_same_calibration() -> None:
    # It was sys.argv[2:] when `calibrate` came first, else the targets and --out alone: `phri -v
    # calibrate ...` lost every setting, and a path with a space split in two.
    from phri.cli import build_parser
    from phri.study.cli import _calibrate_command, _calibration_settings

    argv = ["-v", "calibrate", "pilot data.csv", "--out", "p.toml", "--budget", "7", "--free", "spread",
            "--population", "round 2.toml", "--accept-misses"]  # fmt: skip
    args = build_parser().parse_args(argv)
    command = _calibrate_command(args, _calibration_settings(args))
    words = shlex.split(command)
    assert words[:2] == ["phri", "calibrate"]
    again = build_parser().parse_args(words[1:])
    settings = _calibration_settings(args)
    assert (settings.budget, settings.free, settings.participants) == (7, ("spread",), 5)
    assert _calibration_settings(again) == settings
    assert (again.targets, again.out, again.population, again.accept_misses) == (
        "pilot data.csv", Path("p.toml"), "round 2.toml", True,
    )  # fmt: skip
    defaults = build_parser().parse_args(["calibrate", "corl2017", "--out", "p.toml"])
    assert f"--free {','.join(DEFAULT_FREE)}" in _calibrate_command(defaults, _calibration_settings(defaults))


def test_cli_calibrate_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "p.toml"
    bad = tmp_path / "t.csv"
    bad.write_text("task,strategy,effort\nkitchen,impedance,3\n")
    assert cli(["calibrate", str(bad), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"phri calibrate: error: {bad}: task: unknown task 'kitchen'; known: "), err
    assert cli(["calibrate", str(tmp_path / "none.csv"), "--out", str(out)]) == 2
    assert "targets file not found" in capsys.readouterr().err
    assert cli(["calibrate", "corl2017", "--out", str(out), "--free", "strength.median"]) == 2
    assert "free: unknown parameter 'strength'" in capsys.readouterr().err
    out.write_text("")
    assert cli(["calibrate", "corl2017", "--out", str(out)]) == 2
    assert "never overwritten" in capsys.readouterr().err
    assert not (tmp_path / "none.csv").exists()
