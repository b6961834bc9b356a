"""The README: its two commands first, and its Python example runs as written; so does the example of
the index's short description (PYPI.md)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PYPI = ROOT / "PYPI.md"


def _python_blocks(path: Path) -> list[str]:
    blocks = re.findall(r"```python\n(.*?)```", path.read_text(encoding="utf-8"), re.S)
    assert blocks, f"{path.name} has no Python example"
    return blocks


def test_the_readme_opens_with_the_two_commands() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert lines[:2] == ["# phri", ""] and lines[2] == "```sh"
    assert lines[3].startswith("make demo ") and lines[4].startswith("make test ") and lines[5] == "```"


def test_the_readme_python_example_runs() -> None:
    for block in _python_blocks(README):
        namespace: dict[str, object] = {}
        exec(compile(block, f"{README}:python", "exec"), namespace)  # noqa: S102 - our own README
        assert "learner" in namespace and "tau" in namespace


def test_the_index_descriptions_example_runs() -> None:
    for block in _python_blocks(PYPI):
        namespace: dict[str, object] = {}
        exec(compile(block, f"{PYPI}:python", "exec"), namespace)  # noqa: S102 - our own text
        assert "plan" in namespace
