"""The documentation: every public name has a docstring, the site builds strictly (its API pages from
those docstrings, its tutorial notebook executed), the getting-started page runs as written, and nothing
in the repository points to a file that is not in it."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import os
import pkgutil
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import griffe
import pytest
import yaml

import phri

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS))
from griffe_phri import PhriDocstrings  # noqa: E402 - the docs' own extension, beside mkdocs.yml


def public_modules() -> list[ModuleType]:
    """phri and every module of it whose dotted name has no part starting with "_"."""
    names = ["phri"] + [
        m.name for m in pkgutil.walk_packages(phri.__path__, "phri.")
        if not any(part.startswith("_") for part in m.name.split("."))
    ]  # fmt: skip
    return [importlib.import_module(name) for name in sorted(names)]


def _own_doc(obj: Any) -> str:
    """`obj`'s docstring as written (a dataclass's or named tuple's generated signature is none)."""
    doc = obj.__doc__ if isinstance(obj, type) else inspect.getdoc(obj)
    doc = (doc or "").strip()
    if isinstance(obj, type) and doc.startswith(f"{obj.__name__}("):
        return ""
    return doc


def _members(cls: type) -> list[tuple[str, Any]]:
    """The public methods and properties `cls` defines itself (not inherited)."""
    out = []
    for name, value in vars(cls).items():
        if name.startswith("_"):
            continue
        if isinstance(value, staticmethod | classmethod):
            value = value.__func__
        kind = type(value).__name__
        if inspect.isfunction(value) or isinstance(value, property) or kind in (
            "method_descriptor", "getset_descriptor", "builtin_function_or_method", "classmethod_descriptor",
            "member_descriptor", "cached_property",
        ):  # fmt: skip
            out.append((name, value))
    return out


@pytest.fixture(scope="module")
def api() -> griffe.Module:
    """phri as the docs see it: read by griffe with the docs' extension."""
    loader = griffe.GriffeLoader(
        extensions=griffe.load_extensions(PhriDocstrings), search_paths=[str(ROOT / "python")]
    )
    package = loader.load("phri")
    loader.resolve_aliases(implicit=False, external=False)
    return package  # type: ignore[return-value]


def test_every_public_name_has_a_docstring(api: griffe.Module) -> None:
    """Each public module's docstring; each name in its __all__ (classes, functions, constants); each
    public method and property of those classes."""
    missing = []
    for module in public_modules():
        if not _own_doc(module):
            missing.append(module.__name__)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            where = f"{module.__name__}.{name}"
            if isinstance(obj, ModuleType):
                continue  # documented as a module
            if inspect.isclass(obj) or callable(obj):
                if not _own_doc(obj):
                    missing.append(where)
                if inspect.isclass(obj):
                    missing += [f"{where}.{m}" for m, value in _members(obj) if not _own_doc(value)]
            else:  # a constant: its docstring is its ``#:`` comment, as the docs read it
                documented = api[
                    module.__name__.removeprefix("phri.") + "." + name if module.__name__ != "phri" else name
                ]
                if documented.is_alias:
                    documented = documented.final_target
                if documented.docstring is None or not documented.docstring.value.strip():
                    missing.append(where)
    assert not missing, f"{len(missing)} public names without a docstring: {missing}"


def test_every_public_module_has_an_api_page() -> None:
    documented = set()
    for page in (DOCS / "api").glob("*.md"):
        documented |= set(re.findall(r"^::: ([\w.]+)", page.read_text(encoding="utf-8"), re.M))
    modules = {m.__name__ for m in public_modules()}
    assert modules <= documented, sorted(modules - documented)
    assert documented <= modules, sorted(documented - modules)  # no page for a module that is gone


def _nav_files(nav: Any) -> list[str]:
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, dict):
        return [f for v in nav.values() for f in _nav_files(v)]
    return [f for item in nav for f in _nav_files(item)]


def test_every_page_is_in_the_nav() -> None:
    config = yaml.load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"), Loader=yaml.BaseLoader)
    in_nav = set(_nav_files(config["nav"]))
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*") if p.suffix in (".md", ".ipynb")}
    assert pages == in_nav, (sorted(pages - in_nav), sorted(in_nav - pages))


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(encoding="utf-8"), re.S)


def test_the_getting_started_page_runs_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blocks = _python_blocks(DOCS / "getting-started.md")
    assert len(blocks) >= 2
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, Any] = {}
    for k, block in enumerate(blocks):  # one session, in the page's order
        exec(compile(block, f"getting-started.md:python[{k}]", "exec"), namespace)  # noqa: S102
    assert namespace["learner"].weights[namespace["task"].task_index] > 0


def test_the_features_page_runs_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The "your own feature" page: its files (blocks whose first line is ``# file: PATH``) are
    written, its other Python blocks run in one session, in the page's order."""
    text = (DOCS / "features.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```(python|toml)\n(.*?)```", text, re.S)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    namespace: dict[str, Any] = {}
    written = run = 0
    for k, (language, block) in enumerate(blocks):
        if m := re.match(r"# file: (\S+)\n", block):
            (tmp_path / m.group(1)).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / m.group(1)).write_text(block, encoding="utf-8")
            written += 1
        elif language == "python":
            exec(compile(block, f"features.md:python[{k}]", "exec"), namespace)  # noqa: S102
            run += 1
    assert (written, run) == (2, 2)
    assert namespace["learner"].weights[namespace["task"].task_index] > 1.0


def test_the_command_line_page_has_every_command() -> None:
    from phri.cli import build_parser

    text = (DOCS / "cli.md").read_text(encoding="utf-8")
    parser = build_parser()
    (commands,) = [a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction"]
    for name in commands.choices:  # type: ignore[attr-defined]
        assert f"## phri {name}\n" in text, name


def test_the_files_page_has_every_key() -> None:
    from phri import config
    from phri.study import StudyConfig

    text = (DOCS / "files.md").read_text(encoding="utf-8")
    for key in (*config.TASK_KEYS, *config.WEIGHT_KEYS, *config.SCENE_OBJECT_KEYS):
        assert f"`{key}`" in text or f"`[{key}." in text or f"`[{key}]`" in text, key
    for parameters in phri._phri.FEATURE_PARAMETERS.values():
        for key in parameters:
            assert f"`{key}`" in text, key
    for field in dataclasses.fields(StudyConfig):
        assert field.name == "strategies" or f"{field.name}" in text, field.name


@pytest.mark.slow
def test_the_site_builds_strictly_with_the_api_from_the_docstrings_and_the_tutorial_run(
    tmp_path: Path,
) -> None:
    """`mkdocs build --strict` (a warning fails it: a broken link, a missing page, a notebook cell that
    raises). The API pages carry the compiled module's docstrings with the stubs' types, the tutorial
    its plots, the concepts page its equations as MathML."""
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert "WARNING -" not in done.stderr, done.stderr  # mkdocs' own (strict makes them fatal too)
    api = (site / "api" / "phri" / "index.html").read_text(encoding="utf-8")
    first_words = phri.Robot.frame_pose.__doc__.split("`")[0]  # "Homogeneous 4×4 pose of "
    assert len(first_words) > 10 and first_words in api  # the docstring, from the compiled module
    assert "frame_pose" in api and "_Array" in api  # the signature, from the stubs
    tutorial = (site / "tutorial" / "index.html").read_text(encoding="utf-8")
    assert tutorial.count("data:image/png;base64") >= 2, "the tutorial's plots are missing"
    assert "Traceback" not in tutorial and "Error" not in tutorial.split("mean cup height")[0][-2000:]
    assert "mean cup height after 4 s" in tutorial  # its cells ran
    concepts = (site / "concepts" / "index.html").read_text(encoding="utf-8")
    assert concepts.count("<math") >= 6 and "\\arg" not in concepts
    cli = (site / "cli" / "index.html").read_text(encoding="utf-8")
    assert "--no-frames" in cli and "--allow-version-change" in cli  # the help, as phri prints it now


# -- nothing points outside the repository ---------------------------------------------------------------

#: Files people read: what the repository ships and documents.
_TEXT = (".md", ".py", ".pyi", ".toml", ".rs", ".yml", ".cff", ".urdf", ".ipynb", ".txt")
#: Top-level folders a path in the text may start with.
_TOP = ("crates/", "python/", "tests/", "benches/", "docs/", ".ci/")


def _tracked() -> list[Path]:
    listed = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True,
                            text=True, check=True).stdout.split()  # fmt: skip
    return [ROOT / f for f in listed if f.endswith(_TEXT) and (ROOT / f).is_file()]


def test_nothing_in_the_repository_points_to_a_file_that_is_not_in_it() -> None:
    """No reference to the project's private notes (or any folder outside the repository), every
    relative link of a Markdown page resolves, and every repository path named in a page or a
    comment (``crates/...``, ``python/...``, ...) exists."""
    outside = re.compile(r"\.\./shared|/work/|original_system\.md|jaco2_model\.md")
    link = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")
    tops = "|".join(re.escape(t) for t in _TOP)
    path = re.compile(rf"(?<![\w./-])((?:{tops})[\w./*-]*\w)")
    broken = []
    for file in _tracked():
        if file == Path(__file__).resolve():
            continue  # this test names what it looks for
        text = file.read_text(encoding="utf-8", errors="replace")
        rel = file.relative_to(ROOT).as_posix()
        broken += [f"{rel}: {m.group(0)}" for m in outside.finditer(text)]
        if file.suffix in (".md", ".ipynb"):
            for target in link.findall(text):
                if "://" in target or target.startswith("mailto:"):
                    continue
                if not (file.parent / target).exists():
                    broken.append(f"{rel}: link {target}")
        # A path from the repository's root, or from the crate the file is in (a crate's tests/).
        bases = [ROOT, *(p for p in file.parents if (p / "Cargo.toml").is_file() and p != ROOT)]
        for found in path.findall(text):
            if not any(any(base.glob(found)) for base in bases):
                broken.append(f"{rel}: {found}")
    assert not broken, broken
