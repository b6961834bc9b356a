"""Watch an episode: a 3D replay in the browser of an episode log (simulated or on the FR3), with
the robot's collision spheres among the scene's objects, the desired path and the plan followed,
the person's push and plots sharing the replay's clock.

``phri view LOG.npz`` (or a study folder) serves it on loopback; ``--html out.html`` writes one
self-contained page that works offline. The page runs three.js r111, bundled with phri.
"""

from __future__ import annotations

import html
from pathlib import Path

from phri.atomic import write_atomic
from phri.exceptions import LogError
from phri.view.page import page_html, write_scripts
from phri.view.replay import read_log, replay_data
from phri.view.serve import ReplayServer
from phri.view.study import StudyEpisode, select, study_episodes

__all__ = [
    "ReplayServer", "StudyEpisode", "episodes", "index_html", "page_html", "read_log", "replay_data",
    "replay_page", "write_replay", "write_scripts",
]  # fmt: skip


def episodes(
    path: str | Path,
    *,
    participant: int | None = None,
    task: str | None = None,
    strategy: str | None = None,
    attempt: int | None = None,
) -> list[StudyEpisode] | Path:
    """What `path` holds to replay: an episode log (returned as its Path) or a study folder (its
    episodes with a log that match the choices given; none matching is a LogError)."""
    path = Path(path)
    if path.is_dir():
        found = select(study_episodes(path), participant=participant, task=task, strategy=strategy,
                       attempt=attempt)  # fmt: skip
        if not found:
            raise LogError(
                f"{path}: no episode with a log matches {_choices(participant, task, strategy, attempt)}"
            )
        return found
    if any(x is not None for x in (participant, task, strategy, attempt)):
        raise LogError(f"{path}: --participant, --task, --strategy and --attempt choose in a study folder, "
                       "not in a log")  # fmt: skip
    return path


def _choices(participant: int | None, task: str | None, strategy: str | None, attempt: int | None) -> str:
    given = {"participant": participant, "task": task, "strategy": strategy, "attempt": attempt}
    picked = [f"{k} {v}" for k, v in given.items() if v is not None]
    return ", ".join(picked) if picked else "(any)"


def replay_page(log: str | Path, *, title: str = "", scripts: str | None = None) -> str:
    """The replay page of the episode log `log` (see :func:`page_html` for `scripts`)."""
    path = Path(log)
    arrays = read_log(path)
    try:
        data = replay_data(arrays, title=title)
    except LogError as e:
        raise LogError(f"{path}: {e}") from None
    return page_html(data, scripts=scripts)


def write_replay(log: str | Path, out: str | Path, *, title: str = "", overwrite: bool = False) -> Path:
    """Writes the self-contained replay page of the episode log `log` to `out` (atomically; an
    existing `out` is a FileExistsError unless `overwrite`)."""
    return write_atomic(Path(out), replay_page(log, title=title).encode("utf-8"), overwrite=overwrite)


def index_html(title: str, items: list[tuple[str, str, str]]) -> str:
    """A page listing replays: `items` are (link, text, note)."""
    rows = "\n".join(
        f'<li><a href="{html.escape(href)}">{html.escape(text)}</a> {html.escape(note)}</li>'
        for href, text, note in items
    )
    return (
        f"<!doctype html><html lang=en><meta charset=utf-8><title>{html.escape(title)}</title>"
        "<style>body{font-family:system-ui,sans-serif;margin:2em}li{margin:.2em 0}</style>"
        f"<h1>{html.escape(title)}</h1><ul>\n{rows}\n</ul></html>"
    )
