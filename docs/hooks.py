"""MkDocs hooks of phri's site (mkdocs.yml loads this file by path).

- Display equations are fenced ``math`` blocks of LaTeX; they become MathML when the site is built
  (latex2mathml), which browsers draw without a script: the site needs nothing from the network.
- ``<!-- phri-help: COMMAND -->`` in a page becomes ``phri COMMAND --help`` as it is now, and
  ``<!-- include: PATH -->`` the file PATH of the repository (e.g. a shipped task file), so the pages
  never restate what the code and the files already say.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
from pathlib import Path
from typing import Any

from latex2mathml.converter import convert

ROOT = Path(__file__).resolve().parents[1]
_HELP = re.compile(r"<!-- phri-help: ?([\w-]*) -->")
_INCLUDE = re.compile(r"<!-- include: ?(\S+) -->")


def math_fence(source: str, language: str, css_class: str, options: Any, md: Any, **kwargs: Any) -> str:
    """A ```` ```math ```` block: the equation as display MathML."""
    return f'<div class="math">{convert(source.strip(), display="block")}</div>'


def on_config(config: Any) -> Any:
    """Registers the ``math`` fence with pymdownx.superfences."""
    fences = config.mdx_configs.setdefault("pymdownx.superfences", {}).setdefault("custom_fences", [])
    fences.append({"name": "math", "class": "math", "format": math_fence})
    return config


def phri_help(command: str) -> str:
    """``phri COMMAND --help`` (``phri --help`` for ""), 80 columns wide: a page's code block."""
    from phri.cli import main

    out = io.StringIO()
    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "80"
    try:
        with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
            main([*command.split(), "--help"])
    finally:
        if previous is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = previous
    return out.getvalue()


def include(path: str) -> str:
    """The repository file `path` (relative to its root); a missing one stops the build."""
    file = ROOT / path
    if not file.is_file():
        raise FileNotFoundError(f"<!-- include: {path} -->: {file} does not exist")
    return file.read_text(encoding="utf-8")


def on_page_markdown(markdown: str, **kwargs: Any) -> str:
    """Replaces the help and include markers of a page by what they name, as code blocks."""
    markdown = _HELP.sub(lambda m: f"```text\n{phri_help(m.group(1)).rstrip()}\n```", markdown)
    return _INCLUDE.sub(
        lambda m: f"```{Path(m.group(1)).suffix[1:]}\n{include(m.group(1)).rstrip()}\n```", markdown
    )
