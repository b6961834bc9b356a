"""The replay page: the bundled template, three.js (r111, MIT; see static/LICENSE-three.txt) and the
viewer's script around one episode's replay data. Self-contained (every script inline: one file
that works offline) or beside shared copies of the scripts (the study report's replays)."""

from __future__ import annotations

import base64
import gzip
import json
from importlib import resources
from pathlib import Path
from typing import Any

from phri.atomic import write_atomic

__all__ = ["SCRIPTS", "page_html", "write_scripts"]

#: The page's scripts, in load order (files of phri/view/static).
SCRIPTS = ("three.min.js", "OrbitControls.js", "viewer.js")


def _static(name: str) -> str:
    return resources.files("phri.view").joinpath("static", name).read_text(encoding="utf-8")


def _packed(data: dict[str, Any]) -> str:
    """`data` as the page holds it: JSON, gzip-compressed (a fifth of the size) and base64-encoded
    (nothing in it can close its <script> element). The same data gives the same page (mtime 0)."""
    text = json.dumps(data, separators=(",", ":"), allow_nan=False).encode("utf-8")
    return base64.b64encode(gzip.compress(text, compresslevel=6, mtime=0)).decode("ascii")


def page_html(data: dict[str, Any], *, scripts: str | None = None) -> str:
    """The replay page of `data` (:func:`phri.view.replay.replay_data`): every script inline, or, with
    `scripts` (a relative URL of a folder :func:`write_scripts` filled), loaded from there."""
    if scripts is None:
        tags = "\n".join(f"<script>\n{_static(s)}\n</script>" for s in SCRIPTS)
    else:
        base = scripts.rstrip("/")
        tags = "\n".join(f'<script src="{base}/{s}"></script>' for s in SCRIPTS)
    template = _static("viewer.html")
    return template.replace("{{DATA}}", _packed(data)).replace("{{SCRIPTS}}", tags)


def write_scripts(folder: Path) -> None:
    """The page's scripts and three.js's license into `folder` (made if missing)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in (*SCRIPTS, "LICENSE-three.txt"):
        write_atomic(folder / name, _static(name).encode("utf-8"))
