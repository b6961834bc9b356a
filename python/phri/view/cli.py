"""``phri view``: replay an episode log, or a study folder's episodes, in the browser."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from phri.exceptions import InvalidParameterError, LogError
from phri.view import episodes, index_html, replay_page, write_replay
from phri.view.serve import ReplayServer
from phri.view.study import StudyEpisode

__all__ = ["add_arguments", "run"]

log = logging.getLogger("phri.view")

DEFAULT_PORT = 8765


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``phri view``'s arguments to `parser`."""
    parser.add_argument("path", type=Path, help="an episode log (.npz) or a study folder")
    pick = parser.add_argument_group("choosing in a study folder (any, if left out)")
    pick.add_argument("--participant", type=int, help="the participant (1-based)")
    pick.add_argument("--task", help="the task's name")
    pick.add_argument("--strategy", choices=("impedance", "learning"), help="the strategy")
    pick.add_argument("--attempt", type=int, help="the attempt (1-based)")
    parser.add_argument("--html", type=Path, metavar="OUT",
                        help="write one self-contained page (works offline) instead of serving")  # fmt: skip
    parser.add_argument("--force", action="store_true", help="with --html: replace OUT if it exists")
    parser.add_argument("--host", default="127.0.0.1", help="loopback address to serve on (127.x.y.z)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help="port to serve on (0: any free one)")


def run(args: argparse.Namespace) -> int:
    """Run ``phri view``: write the page with ``--html``, else serve until Ctrl-C; returns the exit code."""
    found = episodes(args.path, participant=args.participant, task=args.task, strategy=args.strategy,
                     attempt=args.attempt)  # fmt: skip
    if args.html is not None:
        if isinstance(found, list) and len(found) > 1:
            names = ", ".join(e.name for e in found[:6])
            raise _many(len(found), names)
        log_path, title = _one(found)
        try:
            out = write_replay(log_path, args.html, title=title, overwrite=args.force)
        except FileExistsError:
            raise InvalidParameterError(
                f"{args.html} exists: choose another OUT, or --force to replace it"
            ) from None
        print(f"wrote {out}")
        return 0
    server = ReplayServer(_pages(found), host=args.host, port=args.port)
    print(f"phri view: serving {args.path} at {server.url} (Ctrl-C stops)", flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    return 0


def _one(found: list[StudyEpisode] | Path) -> tuple[Path, str]:
    """The log and page title of a single episode: a log given as it is, or a study's first match."""
    return (found, "") if isinstance(found, Path) else (found[0].log, found[0].title)


def _many(count: int, names: str) -> Exception:
    return LogError(
        f"{count} episodes match ({names}{', ...' if count > 6 else ''}): --html writes one; choose with "
        "--participant, --task, --strategy and --attempt"
    )


def _pages(found: list[StudyEpisode] | Path):  # type: ignore[no-untyped-def]
    """The server's pages: the log at /, or the study's list at / and each episode at /episode/NAME."""
    if isinstance(found, Path) or len(found) == 1:
        log_path, title = _one(found)
        page = replay_page(log_path, title=title)  # made once: a bad log is an error before serving
        return lambda path: page if path in ("/", "/index.html") else None
    by_name = {e.name: e for e in found}

    def pages(path: str) -> str | None:
        if path in ("/", "/index.html"):
            items = [(f"/episode/{e.name}", e.title, "" if e.status in ("", "ok") else f"({e.status})")
                     for e in found]  # fmt: skip
            return index_html("phri study: episodes", items)
        if path.startswith("/episode/") and path.removeprefix("/episode/") in by_name:
            e = by_name[path.removeprefix("/episode/")]
            return replay_page(e.log, title=e.title)
        return None

    return pages
