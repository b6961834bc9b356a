"""The package: its license, notice and citation files, its metadata and extras, the core working with
numpy only (the optional modules blocked in a subprocess), and the command line's global options."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import yaml
from conftest import run_without

import phri
from phri import _extras
from phri.cli import configure_logging
from phri.cli import main as cli
from phri.exceptions import MissingExtraError, PhriError

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "python" / "phri"
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
PROJECT = PYPROJECT["project"]


def _requirement_name(requirement: str) -> str:
    return re.split(r"[\s<>=!~;\[]", requirement, maxsplit=1)[0].lower().replace("-", "_")


# -- license, notice, citation ----------------------------------------------------------------------------


def test_license_notice_and_metadata_agree() -> None:
    license_text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert license_text.startswith("BSD 3-Clause License")
    assert "Copyright (c) 2026, the phri developers" in license_text
    assert PROJECT["license"] == "BSD-3-Clause"
    assert PROJECT["license-files"] == ["LICENSE", "NOTICE"]
    notice = (ROOT / "NOTICE").read_text(encoding="utf-8")
    # The notice names the derived file, which exists and says where it comes from.
    urdf = re.search(r"python/phri/robots/jaco2/\S+\.urdf", notice)
    assert urdf is not None and (ROOT / urdf.group(0)).is_file()
    assert "kinova-ros" in (ROOT / urdf.group(0)).read_text(encoding="utf-8")[:1000]
    assert "kinova-ros" in notice and "Copyright (c) 2017, Kinova Robotics inc." in notice
    assert PROJECT["authors"] == [{"name": "the phri developers"}]
    assert "Typing :: Typed" in PROJECT["classifiers"] and (PACKAGE / "py.typed").is_file()
    assert not any(c.startswith("License ::") for c in PROJECT["classifiers"])  # PEP 639: the expression
    assert "urls" not in PROJECT  # none exists yet


def test_citation_file() -> None:
    """CITATION.cff (validated with cffconvert when it was written) keeps the keys CFF 1.2.0 requires,
    the package's version, and the paper as the preferred citation."""
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))
    assert {"cff-version", "message", "title", "authors"} <= set(cff)
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert cff["authors"] == [{"name": "the phri developers"}]
    assert cff["version"] == PROJECT["version"] == phri.__version__
    assert cff["license"] == PROJECT["license"]
    paper = cff["preferred-citation"]
    assert paper["type"] == "conference-paper"
    assert paper["title"] == "Learning Robot Objectives from Physical Human Interaction"
    assert [(a["given-names"], a["family-names"]) for a in paper["authors"]] == [
        ("Andrea", "Bajcsy"), ("Dylan P.", "Losey"), ("Marcia K.", "O'Malley"), ("Anca D.", "Dragan"),
    ]  # fmt: skip
    assert paper["collection-title"] == "Proceedings of the 1st Annual Conference on Robot Learning"
    assert (paper["volume"], paper["start"], paper["end"], paper["year"]) == (78, 217, 226, 2017)
    assert not any("url" in key or "repository" in key for key in (*cff, *paper))


# -- extras -----------------------------------------------------------------------------------------------


def test_the_core_needs_numpy_only_and_each_extra_is_what_phri_imports() -> None:
    assert sorted(_requirement_name(r) for r in PROJECT["dependencies"]) == ["numpy", "tomli"]
    extras = PROJECT["optional-dependencies"]
    for module, extra in _extras.EXTRA_OF.items():
        assert module in {_requirement_name(r) for r in extras[extra]}, (module, extra)
    for extra, inner in _extras.INCLUDES.items():
        assert f"phri[{','.join(inner)}]" in extras[extra], extra
    for extra in ("sim", "study", "parquet", "ray"):  # nothing else in them
        modules = {_requirement_name(r) for r in extras[extra]} - {"phri"}
        assert modules == {m for m, e in _extras.EXTRA_OF.items() if e == extra}, extra
    assert {"test", "dev", "bench", "all"} <= set(extras)


def _imports(path: Path) -> set[str]:
    """Top-level modules `path` imports with an import statement (not under ``if TYPE_CHECKING``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skipped = {
        id(n)
        for node in ast.walk(tree)
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
        for stmt in node.body
        for n in ast.walk(stmt)
    }
    out = set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            out |= {a.name.partition(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.partition(".")[0])
    return out


#: Modules that still import an optional dependency directly (to be routed through require); their
#: callers check for it first (phri demo and a study: pybullet; the demo and the report: matplotlib).
DIRECT = {"sim/world.py": {"pybullet", "matplotlib"}, "plots.py": {"matplotlib"}}


def test_optional_modules_are_imported_through_require() -> None:
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        optional = _imports(path) & {*_extras.EXTRA_OF, "scipy"}
        if optional:
            found[path.relative_to(PACKAGE).as_posix()] = optional
    assert all(path in DIRECT and modules <= DIRECT[path] for path, modules in found.items()), found


def test_require_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    assert _extras.require("pandas").__name__ == "pandas"
    real = _extras.importlib.import_module

    def without_pandas(name: str):  # noqa: ANN202
        if name.partition(".")[0] == "pandas":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        if name == "tqdm":
            raise ModuleNotFoundError("No module named 'colorama'", name="colorama")
        return real(name)

    monkeypatch.setattr(_extras.importlib, "import_module", without_pandas)
    with pytest.raises(MissingExtraError, match=r"^the report needs pandas, which is not installed: "
                       r"pip install 'phri\[study\]'$") as caught:  # fmt: skip
        _extras.require("pandas.api.types", "the report")
    assert isinstance(caught.value, ImportError) and isinstance(caught.value, PhriError)
    with pytest.raises(MissingExtraError, match=r"tqdm is installed but cannot be imported .*colorama"):
        _extras.require("tqdm")
    with pytest.raises(KeyError, match="not one of phri's optional dependencies"):
        _extras.require("yaml")  # pyyaml: a test dependency, not an extra


def test_check_lists_every_missing_module_and_the_fewest_extras(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(_extras, "available", lambda m: m not in ("pybullet", "tqdm", "ray"))
    _extras.check(["pandas", "matplotlib"], "x")
    with pytest.raises(MissingExtraError) as caught:
        _extras.check(["pybullet", "pandas", "tqdm", "ray"], "a study")
    # phri[study] brings phri[sim]: not named twice.
    assert str(caught.value) == (
        "a study needs pybullet, tqdm, ray, which are not installed: pip install 'phri[study,ray]'"
    )
    with pytest.raises(MissingExtraError, match=r"^the demo needs pybullet, which is not installed: "):
        _extras.check(["pybullet"], "the demo")


#: Installs a finder that refuses the modules named in sys.argv[1] (as if not installed).
def test_the_core_and_the_cli_work_with_numpy_only(tmp_path: Path) -> None:
    heavy = {*_extras.EXTRA_OF, "scipy"}
    done = run_without(heavy, """
        import sys
        import numpy as np
        import phri
        from phri.cli import main

        robot = phri.Robot.jaco2()
        q = np.deg2rad([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0])
        assert robot.frame_pose(robot.feature_frame, q).shape == (4, 4)
        assert robot.gravity(q).shape == (7,)
        task = phri.load_task("table")
        features = task.feature_set(robot)
        optimizer = phri.TrajectoryOptimizer(features, duration=task.duration)
        plan, info = optimizer.solve(task.vector("true"), task.start, task.goal)
        assert plan.shape == (task.waypoints, 7)
        for argv in (["tasks"], ["study", "s", "--no-progress"], ["report", "s"], ["demo", "--out", "d"],
                     ["questionnaire", "s", "--import", "a.csv"], ["view", "no-such-log.npz"]):
            print("exit", argv[0], main(argv), file=sys.stderr)
        loaded = sorted(m for m in sys.modules if m.partition(".")[0] in set(sys.argv[1].split(",")))
        print("loaded", loaded)
    """, tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "loaded []" in done.stdout
    assert "table" in done.stdout  # phri tasks
    err = done.stderr
    assert "exit tasks 0" in err
    assert (
        "phri study: error: a study needs pybullet, pandas, tqdm, which are not installed: "
        "pip install 'phri[study]'" in err
    )
    assert "exit study 2" in err and not (tmp_path / "s").exists()
    assert (
        "phri report: error: the report needs pandas, statsmodels, matplotlib, markdown, which are not "
        "installed: "
        "pip install 'phri[study]'" in err
    )
    assert (
        "phri demo: error: the demo needs pybullet, matplotlib, which are not installed: "
        "pip install 'phri[sim]'" in err
    )
    assert (
        "phri questionnaire: error: the questionnaire needs pandas, which is not installed: "
        "pip install 'phri[study]'" in err
    )
    assert "phri view: error: no-such-log.npz" in err
    for command in ("report", "demo", "questionnaire", "view"):
        assert f"exit {command} 2" in err
    assert "Traceback" not in err


@pytest.mark.slow
def test_a_study_without_parquet_and_its_progress_bar_off_a_terminal(tmp_path: Path) -> None:
    """Without phri[parquet] a study keeps results.csv only; off a terminal no progress bar is drawn
    (no carriage returns in a log) although none was turned off."""
    done = run_without({"pyarrow", "ray"}, """
        from phri.cli import main
        raise SystemExit(main(["study", "s", "--participants", "1", "--attempts", "1", "--tasks", "laptop",
                               "--duration", "8", "--waypoints", "4", "--knots", "0", "--backend", "serial",
                               "--max-episodes", "1"]))
    """, tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "1 of 2 episodes recorded" in done.stdout
    assert (tmp_path / "s" / "results.csv").is_file() and not (tmp_path / "s" / "results.parquet").exists()
    assert "\r" not in done.stderr and "episode/s" not in done.stderr
    assert (
        "results.parquet not written: pyarrow is not installed (pip install 'phri[parquet]')" in done.stderr
    )


# -- command line -----------------------------------------------------------------------------------------


def test_version_and_python_m_phri(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stopped:
        cli(["--version"])
    assert stopped.value.code == 0 and capsys.readouterr().out == f"phri {phri.__version__}\n"
    done = subprocess.run(
        [sys.executable, "-m", "phri", "tasks"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0 and "laptop" in done.stdout, done.stderr
    usage = subprocess.run([sys.executable, "-m", "phri"], capture_output=True, text=True, timeout=120)
    assert usage.returncode == 2 and usage.stderr.startswith("usage: phri ")


def test_phri_tasks_lists_every_task_with_its_robot_in_aligned_columns(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from phri.config import task_names

    assert cli(["tasks"]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert [r.split()[0] for r in rows] == task_names()
    assert {r.split()[1] for r in rows} == {"jaco2", "fr3"}
    # The robot and the title start in the same column on every row, however long the name.
    columns = [re.match(r"(\S+\s+)(\S+\s+)", r) for r in rows]
    assert all(columns)
    assert len({(len(m[1]), len(m[1]) + len(m[2])) for m in columns if m}) == 1


@pytest.mark.parametrize(
    ("flags", "level"),
    [([], "INFO"), (["-v"], "DEBUG"), (["-vv"], "DEBUG"), (["-q"], "WARNING"), (["-qq"], "ERROR"),
     (["-q", "-v"], "INFO")],
)  # fmt: skip
def test_quiet_and_verbose_set_phris_log_level(flags: list[str], level: str) -> None:
    import logging

    logger = logging.getLogger("phri")
    try:
        assert cli([*flags, "tasks"]) == 0
        assert logging.getLevelName(logger.level) == level
        assert sum(isinstance(h, logging.StreamHandler) for h in logger.handlers) == 1  # replaced, not added
    finally:
        configure_logging()
        logger.setLevel(logging.NOTSET)


def test_the_library_does_not_print() -> None:
    """Library code logs; only the command-line modules print (and the simulator server its ready line)."""
    printing = sorted(
        path.relative_to(PACKAGE).as_posix()
        for path in PACKAGE.rglob("*.py")
        if any(
            isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "print"
            for n in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
        )
    )
    commands = {"cli.py", "study/cli.py", "view/cli.py", "franka/run.py", "franka/sim_server.py"}
    assert set(printing) <= commands, printing


def test_hostile_command_lines_are_clear_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 16 #11: an empty task list and a negative demo seed are errors naming the argument,
    before any folder is made."""
    assert cli(["study", str(tmp_path / "s"), "--tasks", ""]) == 2
    assert "--tasks: must name at least one task" in capsys.readouterr().err
    assert cli(["demo", "--seed", "-1", "--out", str(tmp_path / "demo")]) == 2
    assert "seed must be an integer >= 0, got -1" in capsys.readouterr().err
    assert not (tmp_path / "s").exists() and not (tmp_path / "demo").exists()


# -- the wheel --------------------------------------------------------------------------------------------


def test_the_makefile_installs_every_extras_requirement() -> None:
    """`make dev` installs the requirements of every extra the tests, the docs and the lint need."""
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    installed = {
        _requirement_name(r) for r in re.findall(r'"([A-Za-z][^"]*)"', makefile.split("$(DEPS):")[1])
    }
    extras = PROJECT["optional-dependencies"]
    wanted = {
        _requirement_name(r)
        for extra in ("all", "study", "sim", "parquet", "ray", "franka", "franka-sim", "docs", "dev", "test")
        for r in extras[extra]
    } - {"phri"}
    assert wanted <= installed, sorted(wanted - installed)


def _wheel() -> Path:
    """The wheel as CI ships it: `make wheel` packs the build `make dev` made (cargo reuses it)."""
    done = subprocess.run(["make", "--no-print-directory", "-s", "wheel"], cwd=ROOT, capture_output=True,
                          text=True, timeout=1200)  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    (wheel,) = (ROOT / "dist").glob("phri-*.whl")
    return wheel


@pytest.mark.slow
def test_the_wheel_is_abi3_manylinux2014_stripped_complete_and_runs_the_demo_in_a_fresh_venv(
    tmp_path: Path,
) -> None:
    wheel = _wheel()
    # One wheel for CPython >= 3.10 (the stable ABI), for glibc >= 2.17 (manylinux2014), as its tags say
    # and as auditwheel reads the extension's symbols.
    assert wheel.name.endswith("-cp310-abi3-manylinux2014_x86_64.manylinux_2_17_x86_64.whl"), wheel.name
    shown = subprocess.run([sys.executable, "-m", "auditwheel", "show", str(wheel)], capture_output=True,
                           text=True, timeout=120, check=True).stdout  # fmt: skip
    assert 'consistent with the following platform tag:\n"manylinux_2_17_x86_64"' in shown, shown
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        (extension,) = [n for n in names if n.endswith(".so")]
        assert extension == "phri/_phri.abi3.so"
        z.extract(extension, tmp_path)
        metadata = z.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    # The robot descriptions, the task files, the stubs and the typing marker ship inside it.
    data = (".urdf", ".toml", ".pyi", ".typed", ".js", ".html")
    shipped = {p.relative_to(ROOT / "python").as_posix() for p in PACKAGE.rglob("*")
               if p.is_file() and (p.suffix in data or p.name == "NOTICE")}  # fmt: skip
    assert {"phri/robots/jaco2/j2s7s300.urdf", "phri/robots/fr3/fr3.urdf", "phri/tasks/table.toml",
            "phri/py.typed", "phri/_phri.pyi", "phri/view/static/three.min.js",
            "phri/view/static/viewer.html"} <= shipped <= names, sorted(shipped - names)  # fmt: skip
    assert "phri/view/static/LICENSE-three.txt" in names
    # Stripped: no symbol table left in the extension.
    sections = subprocess.run(["readelf", "-S", "-W", str(tmp_path / extension)], capture_output=True,
                              text=True, timeout=60, check=True).stdout  # fmt: skip
    assert ".dynsym" in sections and ".symtab" not in sections and ".debug_info" not in sections
    # The index page's text is the short one, which starts with `pip install`.
    description = metadata.split("\n\n", 1)[1]
    assert description.strip() == (ROOT / PROJECT["readme"]).read_text(encoding="utf-8").strip()
    first, second = description.splitlines()[:2]
    assert first == "```sh" and second.startswith("pip install phri "), (first, second)
    # Installed into a fresh environment, away from the source tree, the demo runs.
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    pip = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", f"{wheel}[sim]"],
                         capture_output=True, text=True, timeout=900)  # fmt: skip
    assert pip.returncode == 0, pip.stdout + pip.stderr
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    where = subprocess.run(
        [str(venv / "bin" / "python"), "-c", "import phri; print(phri.__file__)"], cwd=tmp_path, env=env,
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    assert where.stdout.startswith(str(venv)), where.stdout
    demo = subprocess.run([str(venv / "bin" / "phri"), "demo", "--out", "out", "--no-frames"], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=900)  # fmt: skip
    assert demo.returncode == 0, demo.stderr
    rows = [line.split()[:2] for line in demo.stdout.splitlines()[2:]]
    assert rows == [[t, s] for t in ("human", "coffee", "table", "laptop") for s in ("impedance", "learning")]
    assert len(list((tmp_path / "out").glob("path_*.png"))) == 4
    # The viewer's page, from the installed wheel's files, of a log the demo wrote.
    view = subprocess.run([str(venv / "bin" / "phri"), "view", "out/logs/laptop_learning.npz", "--html",
                           "replay.html"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert view.returncode == 0, view.stderr
    assert 'REVISION="111"' in (tmp_path / "replay.html").read_text(encoding="utf-8")
