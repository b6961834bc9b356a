"""The demo (``phri demo``): its table, figures, labelled frames and logs, the scene in its pictures,
a user's task file, and what it keeps when interrupted."""

from __future__ import annotations

import csv
import logging
from pathlib import Path

import matplotlib.figure
import numpy as np
import pytest
from test_sim import shortened  # the study's tasks cut short, as the simulation tests use them

import phri
import phri.cli
import phri.demo
from phri import plots


@pytest.mark.slow
def test_the_demo_writes_its_table_figures_frames_and_logs(tmp_path, capsys, caplog) -> None:
    out = tmp_path / "demo"
    with caplog.at_level(logging.INFO, logger="phri"):
        result = phri.demo.run_demo(out, seed=7)
    assert capsys.readouterr().out == "", "the library prints nothing: it logs"
    assert any(
        r.name == "phri.demo" and "one simulated participant (tolerance" in r.message for r in caplog.records
    )
    table = result.table().splitlines()
    assert table[0].split() == ["task", "strategy", "effort", "time", "cost", "desired", "weight", "clear",
                                "walled", "secs"]  # fmt: skip
    assert [row.split()[:2] for row in table[2:]] == [
        [task, strategy] for task in phri.demo.STUDY_TASKS for strategy in ("impedance", "learning")
    ]
    for task in phri.demo.STUDY_TASKS:
        for kind in ("force", "path", "feature", "weights"):
            assert (result.folder / f"{kind}_{task}.png").is_file()
    assert len(list((result.folder / "frames").glob("*.png"))) == 32
    assert len(list((result.folder / "logs").glob("*.npz"))) == 8
    with open(result.folder / "summary.csv", newline="") as f:
        assert len(list(csv.DictReader(f))) == 8
    again = phri.demo.run_demo(out, seed=7, frames=False)
    assert again.folder != result.folder, "a second run must not overwrite the first"


def test_demo_into_an_existing_file_is_a_clear_error_before_any_episode(
    tmp_path, monkeypatch, capsys
) -> None:
    def no_world(*args, **kwargs):
        raise AssertionError("the demo started simulating")

    monkeypatch.setattr(phri.demo, "World", no_world)
    file = tmp_path / "results.txt"
    file.write_text("keep me")
    for out in (file, file / "demo"):
        assert phri.cli.main(["demo", "--out", str(out), "--no-frames"]) == 2
        captured = capsys.readouterr()
        assert captured.out == ""
        assert captured.err.startswith(f"phri demo: error: --out {out} is ")
        assert "a file" in captured.err
    assert file.read_text() == "keep me"
    assert sorted(tmp_path.iterdir()) == [file]


@pytest.fixture
def recorded(monkeypatch) -> dict[str, matplotlib.figure.Figure]:
    """Every figure matplotlib saves, by file name (the figure itself, to inspect what it draws)."""
    figures: dict[str, matplotlib.figure.Figure] = {}
    savefig = matplotlib.figure.Figure.savefig

    def recording_savefig(fig, path, *args, **kwargs):
        figures[Path(path).name] = fig
        return savefig(fig, path, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", recording_savefig)
    return figures


@pytest.fixture
def short_tasks(monkeypatch):
    """The demo's study tasks are table and laptop, cut to 2 s."""
    monkeypatch.setattr(phri.demo, "STUDY_TASKS", ("table", "laptop"))
    monkeypatch.setattr(phri.demo, "load_task", lambda name: shortened(phri.load_task(name), 2.0, 5))


def _lines(ax) -> dict[str, float]:
    """The labelled lines of `ax` and where each ends on the x axis."""
    return {line.get_label(): float(np.max(line.get_xdata())) for line in ax.lines
            if not line.get_label().startswith("_")}  # fmt: skip


def test_the_demos_pictures_show_the_scene_the_feature_the_weights_and_label_the_frames(
    short_tasks, recorded, tmp_path
) -> None:
    result = phri.demo.run_demo(tmp_path / "demo", seed=7, tasks=("table", "laptop"))
    for task in ("table", "laptop"):
        for strategy in ("impedance", "learning"):
            frames = sorted(p.name for p in (result.folder / "frames").glob(f"{task}_{strategy}_t*.png"))
            assert frames == [f"{task}_{strategy}_t{t}.png" for t in ("00.00", "00.67", "01.33", "02.00")]
            # Each frame names its task, strategy and time.
            assert [t.get_text() for t in recorded[frames[1]].texts] == [f"{task} · {strategy} · t = 0.67 s"]
        top, side = recorded[f"path_{task}.png"].axes
        # Every curve of the time axes ends with the task.
        assert _lines(side) == {"desired": 2.0, "impedance": 2.0, "learning": 2.0}
        (feature,) = recorded[f"feature_{task}.png"].axes
        assert _lines(feature) == {"impedance": 2.0, "learning": 2.0, "desired": 2.0}
        assert feature.get_ylabel() == plots.FEATURE_LABELS[task]
        (weights,) = recorded[f"weights_{task}.png"].axes
        assert weights.get_ylabel() == f"w[{task}]" and max(_lines(weights).values()) == 2.0
        # The scene from above: table, laptop and person, the start and goal, and the robot's base.
        names = {t.get_text() for t in top.texts}
        assert {"table", "laptop", "person", "start", "goal", "robot base"} <= names
        assert sum(type(p).__name__ == "Polygon" for p in top.patches) == 3
        # The height panel: the furniture's tops, the start and the goal.
        assert {"table top", "laptop top", "start", "goal"} <= {t.get_text() for t in side.texts}
    # The laptop task's keep-out circle, where its feature puts it.
    top = recorded["path_laptop.png"].axes[0]
    (circle,) = [p for p in top.patches if type(p).__name__ == "Circle"]
    laptop = phri.load_task("laptop")
    (centre, radius) = laptop.keep_out_circle("laptop")
    assert circle.center == pytest.approx(centre) and circle.radius == pytest.approx(radius)
    assert "laptop keep-out (0.4 m)" in {t.get_text() for t in top.texts}
    # The report's colours.
    (impedance,) = [
        line for line in recorded["force_table.png"].axes[0].lines if line.get_label() == "impedance"
    ]
    assert impedance.get_color() == plots.STUDY_COLORS["impedance"]


def test_the_coffee_tasks_feature_is_the_cups_tilt(monkeypatch, recorded, tmp_path) -> None:
    monkeypatch.setattr(phri.demo, "load_task", lambda name: shortened(phri.load_task(name), 2.0, 5))
    phri.demo.run_demo(tmp_path / "demo", seed=7, frames=False, tasks=("coffee",))
    (ax,) = recorded["feature_coffee.png"].axes
    assert "tilt" in ax.get_ylabel()
    values = {line.get_label(): line.get_ydata() for line in ax.lines}
    assert all(np.all(v >= 0) and np.all(v <= 2) for v in values.values())  # |x_x| + |x_y| of a unit axis


def test_phri_demo_runs_a_users_task_file(tmp_path, capsys) -> None:
    """`phri demo --task FILE` runs the task in the file (here the table task renamed and cut to 2 s),
    prints its rows and names its figures after it."""
    short = shortened(phri.load_task("table"), 2.0, 7)
    text = (Path(phri.__file__).parent / "tasks" / "table.toml").read_text(encoding="utf-8")
    goal = ", ".join(f"{g:.6f}" for g in np.rad2deg(short.goal))
    lines = []
    for line in text.splitlines():
        key = line.partition("=")[0].strip()
        line = {"name": 'name = "my_table"', "duration": "duration = 2.0", "waypoints": "waypoints = 7",
                "goal": f"goal = [{goal}]"}.get(key, line)  # fmt: skip
        lines.append(line)
    task_file = tmp_path / "my_table.toml"
    task_file.write_text("\n".join(lines) + "\n", encoding="utf-8")
    out = tmp_path / "demo"
    assert phri.cli.main(["-q", "demo", "--task", str(task_file), "--out", str(out), "--no-frames"]) == 0
    printed = capsys.readouterr()
    assert printed.err == ""  # -q: no progress lines
    rows = [line.split()[:2] for line in printed.out.splitlines()[2:]]
    assert rows == [["my_table", "impedance"], ["my_table", "learning"]]
    assert sorted(p.name for p in out.glob("*.png")) == [
        f"{kind}_my_table.png" for kind in ("feature", "force", "path", "weights")
    ]


@pytest.mark.parametrize(
    ("tasks", "match"),
    [((), "give one or more tasks"), ("table", "give one or more tasks"), (("table", "table"), "twice")],
)
def test_bad_demo_tasks_are_a_clear_error_before_anything_is_written(tasks, match, tmp_path) -> None:
    with pytest.raises(phri.exceptions.InvalidParameterError, match=match):
        phri.demo.run_demo(tmp_path / "demo", tasks=tasks)
    assert not (tmp_path / "demo").exists()
    assert (
        phri.cli.main(["demo", "--task", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "d")]) == 2
    )
    assert not (tmp_path / "d").exists()


def test_a_task_the_demo_cannot_run_is_refused_before_anything_is_written(tmp_path, capsys) -> None:
    """The demo simulates the JACO2: an FR3 task is refused, naming the task file and the robot, and
    no output folder is left behind."""
    out = tmp_path / "demo"
    assert phri.cli.main(["-q", "demo", "--task", "table", "--task", "fr3_table", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "fr3_table.toml" in err and "'fr3'" in err, err
    assert not out.exists()


def test_an_interrupted_demo_keeps_the_rows_of_the_episodes_it_finished(
    short_tasks, tmp_path, monkeypatch
) -> None:
    run, calls = phri.demo.run_episode_for_demo, {"n": 0}

    def interrupted(*args):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return run(*args)

    monkeypatch.setattr(phri.demo, "run_episode_for_demo", interrupted)
    out = tmp_path / "demo"
    with pytest.raises(KeyboardInterrupt):
        phri.demo.run_demo(out, seed=7, frames=False)
    with open(out / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["task"], r["strategy"]) for r in rows] == [("table", "impedance"), ("table", "learning")]
    assert float(rows[1]["effort"]) >= 0
