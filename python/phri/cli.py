"""The ``phri`` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from phri.exceptions import PhriError

__all__ = ["main"]


def _demo(args: argparse.Namespace) -> int:
    from phri.demo import run_demo

    run_demo(Path(args.out), seed=args.seed, gui=args.gui, frames=not args.no_frames)
    return 0


def _tasks(args: argparse.Namespace) -> int:
    from phri.config import load_task, task_names

    for name in task_names():
        task = load_task(name)
        print(f"{name:<8} {task.title}  (features: {', '.join(task.feature_names)})")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="phri", description="Learning robot objectives from physical human interaction."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="the four study tasks, both strategies, one simulated participant")
    demo.add_argument("--out", default="out/demo", help="output folder (a fresh one is made if it exists)")
    demo.add_argument("--seed", type=int, default=7, help="seed of the simulated participant")
    demo.add_argument("--gui", action="store_true", help="show the PyBullet window")
    demo.add_argument("--no-frames", action="store_true", help="skip rendering PNG frames")
    demo.set_defaults(run=_demo)
    tasks = sub.add_parser("tasks", help="list the shipped tasks")
    tasks.set_defaults(run=_tasks)
    from phri.study.cli import register as register_study

    register_study(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args))
    except PhriError as e:
        print(f"phri {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
