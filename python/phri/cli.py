"""The ``phri`` command line (also ``python -m phri``).

Global options: ``--version``; ``-v``/``-q`` (repeatable) raise or lower what phri's ``logging``
shows on stderr (default: info and above; ``-q`` also hides the progress bar). Results go to stdout.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Any

from phri.exceptions import PhriError

__all__ = ["add_global_options", "build_parser", "configure_logging", "main"]


class _Stderr(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is when a record comes (tests and tools replace it)."""

    @property
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, value: object) -> None:
        pass


#: The handler :func:`configure_logging` put on the "phri" logger (replaced by the next call).
_handler: logging.Handler | None = None


def add_global_options(parser: argparse.ArgumentParser) -> None:
    """``--version``, ``-v``/``--verbose`` and ``-q``/``--quiet`` on `parser`."""
    from phri import __version__

    parser.add_argument("--version", action="version", version=f"phri {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="show more of phri's log (-v: debug)")  # fmt: skip
    parser.add_argument("-q", "--quiet", action="count", default=0,
                        help="show less: -q warnings only and no progress bar, -qq errors only")  # fmt: skip


def configure_logging(verbose: int = 0, quiet: int = 0) -> int:
    """Sends the "phri" logger's records to stderr from the level INFO + 10·(`quiet` − `verbose`)
    (clamped to DEBUG..CRITICAL) on; returns that level. Each call replaces the previous one's handler."""
    global _handler
    level = min(max(logging.INFO + 10 * (quiet - verbose), logging.DEBUG), logging.CRITICAL)
    logger = logging.getLogger("phri")
    if _handler is not None:
        logger.removeHandler(_handler)
    _handler = _Stderr()
    _handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    logger.addHandler(_handler)
    logger.setLevel(level)
    return level


def _demo(args: argparse.Namespace) -> int:
    from phri._extras import check_part

    check_part("the demo")
    from phri.demo import run_demo, table_header, table_row

    header = {"printed": False}

    def print_row(result: Any) -> None:
        if not header["printed"]:
            print(table_header())
            header["printed"] = True
        print(table_row(result), flush=True)

    run_demo(Path(args.out), seed=args.seed, gui=args.gui, frames=not args.no_frames,
             tasks=args.task, on_episode=print_row, simulator=args.simulator)  # fmt: skip
    return 0


def _tasks(args: argparse.Namespace) -> int:
    from phri.config import load_task, task_names

    names = task_names()
    width = max(map(len, names))
    for name in names:
        task = load_task(name)
        print(f"{name:<{width}}  {task.robot:<5}  {task.title}  (features: {', '.join(task.feature_names)})")
    return 0


def _sim_server(args: argparse.Namespace) -> int:
    from phri._extras import require

    require("franky_sim", "phri sim-server")
    from phri.franka.sim_server import run

    return run(args)


def _run(args: argparse.Namespace) -> int:
    from phri._extras import require

    require("pylibfranka", "phri run")
    require("matplotlib", "phri run's figures")
    from phri.franka.run import run

    return run(args)


def _view(args: argparse.Namespace) -> int:
    from phri.view.cli import run

    return run(args)


def build_parser() -> argparse.ArgumentParser:
    """The ``phri`` command's argument parser, with every subcommand."""
    parser = argparse.ArgumentParser(
        prog="phri", description="Learning robot objectives from physical human interaction."
    )
    add_global_options(parser)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser(
        "demo", help="the four study tasks (or --task), both strategies, one simulated participant"
    )
    demo.add_argument("--out", default="out/demo", help="output folder (a fresh one is made if it exists)")
    demo.add_argument(
        "--seed", type=int, default=7, help="seed of the participant's tremor and aim and of the sensor"
    )
    demo.add_argument("--gui", action="store_true", help="show the PyBullet window")
    demo.add_argument("--no-frames", action="store_true", help="skip rendering PNG frames")
    demo.add_argument("--simulator", choices=("native", "pybullet"), default=None,
                      help="what simulates the episodes (default native; pybullet with --gui, whose window "
                      "shows PyBullet's arm)")  # fmt: skip
    demo.add_argument("--task", action="append", metavar="TASK",
                      help="a shipped task's name or a task file (.toml) to run instead of the study's four; "
                      "repeat for several")  # fmt: skip
    demo.set_defaults(run=_demo)
    tasks = sub.add_parser("tasks", help="list the shipped tasks")
    tasks.set_defaults(run=_tasks)
    from phri.franka.sim_server import DEFAULT_HOST, add_arguments

    sim_server = sub.add_parser(
        "sim-server",
        help=f"franky-sim's FR3 with a task's scene and simulated participant on a loopback address "
        f"(default {DEFAULT_HOST}) until Ctrl-C",
    )
    add_arguments(sim_server)
    sim_server.set_defaults(run=_sim_server)
    from phri.franka.run import add_arguments as add_run_arguments

    run = sub.add_parser(
        "run",
        help="one episode on the arm at an address (a real FR3, or `phri sim-server`): the log, "
        "figures and a summary, as the simulated episodes write them",
    )
    add_run_arguments(run)
    run.set_defaults(run=_run)
    from phri.view.cli import add_arguments as add_view_arguments

    view = sub.add_parser(
        "view",
        help="replay an episode log (or a study's episodes) in the browser: served on loopback, or "
        "--html writes one offline page",
    )
    add_view_arguments(view)
    view.set_defaults(run=_view)
    from phri.study.cli import register as register_study

    register_study(sub)
    return parser


def file_error(command: str, error: OSError) -> int:
    """A file operation the system refused (read-only folder, no permission, disk full): one line
    naming the file, never a traceback. phri's writes are atomic, so nothing written before is lost."""
    what = error.strerror or str(error)
    where = f" ({error.filename})" if error.filename else ""
    print(
        f"phri {command}: error: {what}{where}; nothing already written was changed or lost", file=sys.stderr
    )
    return 3


def main(argv: list[str] | None = None) -> int:
    """Runs ``phri`` with `argv` (None: the process's arguments); returns the exit status: 0 done,
    2 a usage or input error, 3 a file operation the system refused."""
    args = build_parser().parse_args(argv)
    configure_logging(args.verbose, args.quiet)
    try:
        return int(args.run(args))
    except PhriError as e:
        print(f"phri {args.command}: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        return file_error(args.command, e)


if __name__ == "__main__":
    raise SystemExit(main())
