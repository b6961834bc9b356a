"""Command-line front ends: ``phri study``, ``phri report``, ``phri questionnaire`` and
``phri calibrate``.

``register(subparsers)`` adds the four subcommands to phri's main parser; each sets ``run`` (call
``args.run(args)``: an exit code; errors are printed as ``phri <command>: error: ...`` and give 2).
``python -m phri.study`` runs them without phri's main CLI.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import shlex
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from phri._phri import UPDATE_RULES
from phri.cli import file_error
from phri.exceptions import PhriError

if TYPE_CHECKING:
    from phri.study.calibrate import CalibrationSettings

__all__ = ["main", "register"]

logger = logging.getLogger(__name__)

_STUDY_KEYS = (
    "participants", "attempts", "seed", "tasks", "familiarization", "duration", "waypoints", "knots",
    "sample_rate", "sensor_noise", "rule", "risk", "population",
)  # fmt: skip


def _names(text: str) -> tuple[str, ...]:
    return tuple(t.strip() for t in text.split(",") if t.strip())


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Adds ``study``, ``report``, ``questionnaire`` and ``calibrate`` to `subparsers`."""
    _add_study(subparsers)
    _add_report(subparsers)
    _add_calibrate(subparsers)
    _add_questionnaire(subparsers)


def _add_study(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    s = subparsers.add_parser(
        "study",
        help="run (or resume) the simulated user study into a folder",
        description="Runs the paper's user study with simulated participants into RUN_DIR: per participant "
        "and strategy (order counterbalanced) the familiarization task then tasks 1-3, each attempted twice. "
        "Writes results.csv (a row per episode; also results.parquet with phri[parquet]) and logs/*.npz as "
        "it goes; running it again on the same folder resumes where it stopped. Without study options, a "
        "folder's own study is resumed.",
    )
    s.add_argument("run_dir", type=Path, help="study folder (created if missing)")
    g = s.add_argument_group("the study (defaults: the paper's)")
    g.add_argument(
        "--config", type=Path, help="study TOML file (keys as these options, e.g. participants = 10)"
    )
    g.add_argument("--participants", type=int, help="number of simulated participants (default 10)")
    g.add_argument("--attempts", type=int, help="attempts per task and strategy (default 2)")
    g.add_argument("--seed", type=int, help="study seed (default 0)")
    g.add_argument(
        "--tasks",
        type=_names,
        help="comma-separated task names or TOML files, familiarization first "
        "(default human,coffee,table,laptop)",
    )
    g.add_argument(
        "--familiarization",
        help="the familiarization task, or 'none' (default human when it is among the tasks)",
    )
    g.add_argument("--duration", type=float, help="override every task's duration [s] (the study's: 15)")
    g.add_argument("--waypoints", type=int, help="override every task's number of plan waypoints")
    g.add_argument(
        "--knots",
        type=int,
        help="override every task's plan knots: plans piecewise linear through this many knots, as the "
        "original planned 4; 0 plans every waypoint",
    )
    g.add_argument("--sample-rate", type=float, help="torque sampling rate [Hz] (default 10)")
    g.add_argument("--sensor-noise", type=float, help="torque sensor noise [N·m] (default 0.1)")
    g.add_argument("--rule", choices=UPDATE_RULES, help="weight-update rule (default all)")
    g.add_argument(
        "--risk",
        type=float,
        help="plan with each learned weight this many of the belief's standard deviations above its "
        "estimate (default 0: the estimate, as the paper)",
    )
    g.add_argument(
        "--population",
        help="the simulated participants: a population TOML file (parameter distributions, see "
        "docs/participant.md) or a shipped population's name (default: default)",
    )
    x = s.add_argument_group("execution (does not change the results)")
    x.add_argument("--backend", choices=("serial", "process", "ray"), default="process",
                   help="where episodes run (default: a local process pool)")  # fmt: skip
    x.add_argument("--workers", type=int, help="parallel workers, >= 1 (default: the CPUs available; with "
                   "--backend ray, the Ray cluster's CPUs, all nodes together)")  # fmt: skip
    x.add_argument(
        "--address", help="Ray cluster address, e.g. 'auto' (backend ray; default: a local instance)"
    )
    x.add_argument(
        "--simulator",
        choices=("native", "pybullet"),
        default=None,
        help="what simulates the episodes: the arm and the control loop in Rust (native, the "
        "default) or the Python loop over PyBullet (the reference); they agree within "
        "docs/simulation.md's tolerance",
    )
    x.add_argument("--max-episodes", type=int, help="stop after this many new episodes (resume later)")
    x.add_argument("--ask", action="store_true",
                   help="ask the Table 1 questionnaire on the terminal after each participant's strategy "
                   "(runs serially; answers go to RUN_DIR/questionnaire.csv); on resume, first asks for "
                   "every finished strategy that has no answers yet")  # fmt: skip
    x.add_argument("--allow-version-change", action="store_true",
                   help="resume a folder that another phri version started (its table then mixes "
                   "versions; the default is to refuse)")  # fmt: skip
    x.add_argument("--no-progress", action="store_true",
                   help="no progress bar (it is shown only on a terminal, and not with -q)")  # fmt: skip
    live = s.add_argument_group(
        "the study with real people on a real arm (--live; serial, the questionnaire after each strategy)"
    )
    live.add_argument("--live", action="store_true",
                      help="run the protocol on the arm at --host with the experimenter at the terminal: "
                      "each episode is announced and waits for Enter ('q' pauses; the same command "
                      "resumes)")  # fmt: skip
    live.add_argument("--robot", choices=("fr3",),
                      help="the arm at --host (with --live); its tasks are the fr3_* ones (--tasks table "
                      "is fr3_table; default fr3_human,fr3_coffee,fr3_table,fr3_laptop)")  # fmt: skip
    live.add_argument("--host", help="the robot's address (a real FR3's, or `phri sim-server`'s)")
    live.add_argument("--connect-timeout", type=float, default=None,
                      help="seconds to wait for an answer at --host (default 5)")  # fmt: skip
    live.add_argument("--move-speed", type=float, default=None,
                      help="the move to each episode's start pose: its fastest joint peaks at this "
                      "fraction of its rated speed (default 0.1)")  # fmt: skip
    s.set_defaults(run=cmd_study)


def _add_report(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    r = subparsers.add_parser(
        "report",
        help="statistics, figures and a Markdown report of a study folder",
        description="Analyses RUN_DIR: mean and SD per task and strategy, the paper's factorial ANOVA and a "
        "repeated-measures ANOVA with effect sizes (a test without error variance is reported as not "
        "estimable; a design too small to test gets a warning), Fig. 4 and 5 as PNG and PDF, the tables as "
        "CSV and LaTeX, Table 1 if questionnaire answers exist. Writes a new folder RUN_DIR/report "
        "(RUN_DIR/report-2, -3, ... if it exists: an earlier report is never overwritten) holding report.md.",
    )
    r.add_argument("run_dir", type=Path, help="study folder written by `phri study`")
    r.add_argument(
        "--out", type=Path, help="output folder, made new (default RUN_DIR/report; OUT-2, ... if it exists)"
    )
    r.add_argument(
        "--questionnaire", type=Path, help="Table 1 answers CSV (default RUN_DIR/questionnaire.csv)"
    )
    r.add_argument(
        "--participant", type=int, help="participant shown in the path figure (default: the first)"
    )
    r.add_argument("--task", help="task shown in the path figure (default laptop)")
    r.add_argument(
        "--reference",
        help="reference statistics CSV (the targets format of `phri calibrate`) or a shipped reference "
        "('corl2017': the paper's study): per cell simulated against reference, and the ratios",
    )
    r.set_defaults(run=cmd_report)


def _add_calibrate(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    c = subparsers.add_parser(
        "calibrate",
        help="fit a population of simulated participants to reference statistics",
        description="Fits a population's parameters (by default the push levels, the off-axis push, the "
        "patience, the hold and the spread) so that small simulated studies of the targets' tasks match "
        "the target statistics: Nelder-Mead (scipy) on common random numbers (the same people and "
        "episode seeds for every candidate). TARGETS is a CSV with a row per task and strategy (task, "
        "strategy, effort, interaction_time, effort_per_sample, optional *_sd) and optional pooled F rows "
        "(see docs/participant.md), or 'corl2017'. Prints target against achieved; a calibration that "
        "misses a target by more than --tolerance says which and by how much, writes nothing (unless "
        "--accept-misses) and exits with 1. Run it with `nice` on a shared machine.",
    )
    c.add_argument("targets", help="targets CSV, or a shipped reference name (corl2017)")
    c.add_argument("--out", type=Path, required=True, help="the population TOML to write (must not exist)")
    c.add_argument(
        "--population", help="starting population: a TOML file or a shipped name (default: default)"
    )
    c.add_argument("--participants", type=int, default=5, help="participants per candidate (default 5)")
    c.add_argument("--attempts", type=int, default=1, help="attempts per task and strategy (default 1)")
    c.add_argument("--seed", type=int, default=0, help="seed of the people and the episodes (default 0)")
    c.add_argument("--budget", type=int, default=80, help="most candidates evaluated (default 80)")
    c.add_argument("--free", type=_names, help="comma-separated quantities to fit, 'parameter.key' or "
                   "'spread' (default max_force.median,max_torque.median,off_axis.median,patience.median,"
                   "hold.median,spread)")  # fmt: skip
    c.add_argument("--tolerance", type=float, default=0.2,
                   help="a target is met within this relative difference (default 0.2)")  # fmt: skip
    c.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    c.add_argument("--simulator", choices=("native", "pybullet"), default="native",
                   help="what simulates the episodes (default native)")  # fmt: skip
    c.add_argument("--accept-misses", action="store_true",
                   help="write the population even if it misses targets (recorded in it)")  # fmt: skip
    c.add_argument("--no-progress", action="store_true", help="no progress bar (shown only on a terminal)")
    c.set_defaults(run=cmd_calibrate)


def _add_questionnaire(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    q = subparsers.add_parser(
        "questionnaire",
        help="ask or import the Table 1 questionnaire",
        description="Asks the ten Likert items of the paper's Table 1 on the terminal for one participant "
        "and strategy, or imports a CSV (participant,strategy,q1..q10; raw answers 1-7), into "
        "RUN_DIR/questionnaire.csv. Participants and strategies must be the study's (RUN_DIR/study.json); "
        "existing answers are never changed, and an import with any invalid row adds nothing.",
    )
    q.add_argument("run_dir", type=Path, help="study folder")
    how = q.add_mutually_exclusive_group(required=True)
    how.add_argument("--participant", type=int, help="ask this participant (with --strategy)")
    how.add_argument("--import", dest="import_csv", type=Path, help="import answers from this CSV")
    q.add_argument("--strategy", help="the strategy the participant just used")
    q.set_defaults(run=cmd_questionnaire)


def _study_config(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    from phri.study.errors import StudyConfigError
    from phri.study.protocol import StudyConfig

    given = {k: getattr(args, k) for k in _STUDY_KEYS if getattr(args, k) is not None}
    if "familiarization" in given and given["familiarization"].lower() in ("none", ""):
        given["familiarization"] = None
    robot = getattr(args, "robot", None)
    if robot is not None:
        from phri.study.live import FR3_TASKS

        # The robot's shipped tasks by their short names: "table" is "fr3_table".
        if "tasks" in given:
            given["tasks"] = tuple(_robot_task(t, robot) for t in given["tasks"])
        if given.get("familiarization") is not None:
            given["familiarization"] = _robot_task(given["familiarization"], robot)
        if given and "tasks" not in given and args.config is None:
            given["tasks"] = FR3_TASKS
    if args.config is None and not given:
        return None
    base = StudyConfig.from_toml(args.config).to_dict() if args.config is not None else {}
    if "tasks" in given and not given["tasks"]:
        raise StudyConfigError("--tasks: must name at least one task (comma-separated), got none")
    if "tasks" in given and "familiarization" not in given and "familiarization" not in base:
        first = given["tasks"][0]
        given["familiarization"] = first if first in ("human", f"{robot}_human") else None
    return StudyConfig.from_dict({**base, **given}, str(args.config) if args.config is not None else "study")


def _robot_task(name: str, robot: str) -> str:
    """`name` as `robot`'s shipped task: the name with the robot's prefix if that task ships (a file
    or an unknown name stays as it is, for the study's own checks)."""
    from phri.config import task_names

    if name.endswith(".toml") or "/" in name or name.startswith(f"{robot}_"):
        return name
    return f"{robot}_{name}" if f"{robot}_{name}" in task_names() else name


def _fail(command: str, error: BaseException) -> int:
    print(f"phri {command}: error: {error}", file=sys.stderr)
    return 2


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the study is so that it unwinds as after Ctrl-C: the pool is shut
    down and every recorded episode is kept."""


def _on_sigterm(signum: int, frame: object) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # once: a second SIGTERM must not break the shutdown
    raise _Terminated


@contextlib.contextmanager
def _sigterm_unwinds() -> Iterator[None]:
    """While the study runs, SIGTERM (a service manager, `kill`) unwinds it like Ctrl-C instead of
    killing this process and leaving its pool workers behind."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _questionnaire_hooks(
    args: argparse.Namespace,
) -> tuple[Callable[[int, str], None] | None, Callable[[int, str], bool] | None]:
    """With --ask: `between_strategies` and `answered` for run_study (the questionnaire on the
    terminal); else None and None."""
    if not args.ask:
        return None, None
    from phri.study import questionnaire as q
    from phri.study.report import QUESTIONNAIRE_CSV

    target = args.run_dir / QUESTIONNAIRE_CSV

    def between(participant: int, strategy: str) -> None:
        answers = q.ask(participant, strategy)
        q.append_response(target, participant, strategy, answers)

    def answered(participant: int, strategy: str) -> bool:
        if not target.exists():
            return False
        r = q.read_responses(target)
        return bool(((r["participant"] == participant) & (r["strategy"] == strategy)).any())

    return between, answered


def _live_runner(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """With --live: the runner factory of run_study (the live study on the arm at --host); else
    None. Bad combinations of the live options are a StudyConfigError naming them."""
    from phri.study.errors import StudyConfigError

    live_only = [
        f"--{k.replace('_', '-')}"
        for k in ("robot", "host", "connect_timeout", "move_speed")
        if getattr(args, k) is not None
    ]
    if not args.live:
        if live_only:
            raise StudyConfigError(
                f"study: {', '.join(live_only)} only go with --live (the simulated study runs the "
                "PyBullet JACO2)"
            )
        return None
    if args.robot is None or args.host is None:
        raise StudyConfigError("study: --live needs --robot fr3 and --host ADDRESS (the robot's address)")
    if args.backend != "process" or args.workers is not None or args.address is not None:
        raise StudyConfigError(
            "study: --live runs serially on the arm: leave out --backend, --workers, --address"
        )
    from phri.franka.episode import CONNECT_TIMEOUT
    from phri.franka.move import MOVE_SPEED
    from phri.study.live import LiveRunner, live_tasks

    def make(config, log_width):  # type: ignore[no-untyped-def]
        return LiveRunner(
            config, live_tasks(config, args.robot), log_width, host=args.host, run_dir=args.run_dir,
            robot=args.robot,
            connect_timeout=CONNECT_TIMEOUT if args.connect_timeout is None else args.connect_timeout,
            move_speed=MOVE_SPEED if args.move_speed is None else args.move_speed,
        )  # fmt: skip

    return make


def _live_config(args: argparse.Namespace, config):  # type: ignore[no-untyped-def]
    """The live study's config: `config` (from the options), else the folder's own study, else the
    default study on the robot's tasks; its tasks must be posed for --robot."""
    from phri.study.live import FR3_TASKS, live_tasks
    from phri.study.protocol import StudyConfig
    from phri.study.results import read_manifest

    if config is None:
        found = read_manifest(args.run_dir) if args.run_dir.is_dir() else None
        config = found[0] if found is not None else StudyConfig(tasks=FR3_TASKS, familiarization=FR3_TASKS[0])
    live_tasks(config, args.robot)  # a task for another robot is a ConfigError here, before anything
    return config


def cmd_study(args: argparse.Namespace) -> int:
    from phri._extras import available
    from phri.study.live import StudyPaused

    try:
        from phri.study.run import run_study

        runner = _live_runner(args)
        if runner is not None:
            args.ask = True  # the questionnaire after each strategy, as the paper's study asked it
        between, answered = _questionnaire_hooks(args)
        with _sigterm_unwinds():
            config = _study_config(args)
            if runner is not None:
                config = _live_config(args, config)
            run = run_study(
                args.run_dir, config, backend="live" if runner else "serial" if args.ask else args.backend,
                workers=args.workers, address=args.address, max_episodes=args.max_episodes,
                progress=not args.no_progress and not getattr(args, "quiet", 0) and runner is None,
                between_strategies=between, answered=answered,
                allow_version_change=args.allow_version_change, runner=runner, simulator=args.simulator,
            )  # fmt: skip
    except StudyPaused as e:
        print(
            f"\nphri study: {e}; every finished episode is kept. Resume with: phri study {args.run_dir} "
            f"--robot {args.robot} --host {args.host} --live"
        )
        return 0
    except (PhriError, ImportError, FileExistsError) as e:
        return _fail("study", e)
    except ConnectionError as e:  # e.g. `--backend ray --address auto` with no cluster running
        return _fail(
            "study", ConnectionError(f"cannot reach the Ray cluster at --address {args.address!r}: {e}")
        )
    except OSError as e:
        return file_error("study", e)
    except KeyboardInterrupt as e:
        how = "terminated (SIGTERM)" if isinstance(e, _Terminated) else "interrupted"
        print(
            f"\nphri study: {how}; every finished episode is kept. Run `phri study {args.run_dir}` "
            "to resume.",
            file=sys.stderr,
        )
        return 143 if isinstance(e, _Terminated) else 130
    minutes, seconds = divmod(run.elapsed, 60)
    print(
        f"{run.done} of {run.total} episodes recorded ({run.ran} run now with {run.workers or 0} "
        f"{run.backend} worker(s) in {int(minutes)} min {seconds:.1f} s) -> {args.run_dir / 'results.csv'}"
    )
    if not available("pyarrow"):
        logger.info("results.parquet not written: pyarrow is not installed (pip install 'phri[parquet]')")
    if run.complete:
        print(f"next: phri report {args.run_dir}")
    else:
        print(f"incomplete: run `phri study {args.run_dir}` again to resume")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from phri._extras import check_part

    try:
        check_part("the report")
        from phri.study.report import write_report

        path = write_report(
            args.run_dir,
            args.out,
            questionnaire=args.questionnaire,
            participant=args.participant,
            task=args.task,
            reference=args.reference,
        )
    except PhriError as e:
        return _fail("report", e)
    except OSError as e:
        return file_error("report", e)
    asked = args.out if args.out is not None else args.run_dir / "report"
    if path.parent != asked:
        print(f"{asked} exists and was left as it is; wrote a new folder")
    print(f"report: {path} (figures and tables in {path.parent})")
    return 0


def cmd_questionnaire(args: argparse.Namespace) -> int:
    from phri._extras import check_part

    try:
        check_part("the questionnaire")
        from phri.study import questionnaire as q
        from phri.study.errors import QuestionnaireError
        from phri.study.report import QUESTIONNAIRE_CSV
        from phri.study.results import read_manifest

        target = args.run_dir / QUESTIONNAIRE_CSV
        if not args.run_dir.is_dir():
            raise QuestionnaireError(f"{args.run_dir}: no such study folder")
        found = read_manifest(args.run_dir)
        if found is None:
            raise QuestionnaireError(
                f"{args.run_dir}: no study.json; answers are checked against the study's participants and "
                f"strategies (run `phri study {args.run_dir}` first)"
            )
        study, _ = found
        if args.import_csv is not None:
            added = q.import_responses(args.import_csv, target, study=study)
            print(f"{added} questionnaire(s) added to {target}")
        else:
            if not args.strategy:
                raise QuestionnaireError("questionnaire: --participant needs --strategy")
            # Before the ten items are asked: a wrong participant or strategy wastes no one's time.
            q.check_in_study(
                args.participant, args.strategy, study, "questionnaire", ("--participant", "--strategy")
            )
            answers = q.ask(args.participant, args.strategy)
            q.append_response(target, args.participant, args.strategy, answers, study=study)
            print(f"saved to {target}")
    except PhriError as e:
        return _fail("questionnaire", e)
    except OSError as e:
        return file_error("questionnaire", e)
    return 0


def _calibration_settings(args: argparse.Namespace) -> CalibrationSettings:
    from phri.study.calibrate import DEFAULT_FREE, CalibrationSettings

    return CalibrationSettings(
        participants=args.participants, attempts=args.attempts, seed=args.seed, budget=args.budget,
        free=args.free or DEFAULT_FREE, tolerance=args.tolerance, workers=args.workers,
        simulator=args.simulator,
    )  # fmt: skip


def _calibrate_command(args: argparse.Namespace, settings: CalibrationSettings) -> str:
    """The command that reruns this calibration, every setting spelled out and quoted for a POSIX
    shell, whatever the command line or `main`'s arguments left at their defaults."""
    words = ["phri", "calibrate", str(args.targets), "--out", str(args.out)]
    if args.population:
        words += ["--population", str(args.population)]
    words += ["--participants", str(settings.participants), "--attempts", str(settings.attempts),
              "--seed", str(settings.seed), "--budget", str(settings.budget),
              "--free", ",".join(settings.free), "--tolerance", repr(settings.tolerance),
              "--workers", str(settings.workers), "--simulator", settings.simulator]  # fmt: skip
    if args.accept_misses:
        words.append("--accept-misses")
    return shlex.join(words)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from phri._extras import check_part

    try:
        check_part("a study")
        from phri.sim.participant import load_population
        from phri.study.calibrate import CalibrationError, calibrate, write_population
        from phri.study.targets import read_targets

        if args.out.exists():
            raise FileExistsError(f"{args.out} exists; a population, once written, is never overwritten")
        targets = read_targets(args.targets)
        start = load_population(args.population) if args.population else None
        settings = _calibration_settings(args)
        result = calibrate(
            targets, start, settings, progress=not args.no_progress and not getattr(args, "quiet", 0)
        )
        print(result.table())
        minutes, seconds = divmod(result.elapsed, 60)
        print(f"{result.evaluations} candidates in {int(minutes)} min {seconds:.0f} s; loss "
              f"{result.start.loss:.4g} at the start, {result.best.loss:.4g} at the best")  # fmt: skip
        command = _calibrate_command(args, settings)
        try:
            path = write_population(result, args.out, command=command, accept_misses=args.accept_misses)
        except CalibrationError as e:
            print(f"phri calibrate: {e}", file=sys.stderr)
            return 1
    except (PhriError, ImportError) as e:
        return _fail("calibrate", e)
    except FileExistsError as e:
        return _fail("calibrate", e)
    except OSError as e:
        return file_error("calibrate", e)
    print(
        ("population written (targets missed, as asked): " if not result.reached else "population: ")
        + str(path)
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m phri.study {study,report,questionnaire,calibrate} ...`` (with phri's global options)."""
    from phri.cli import add_global_options, configure_logging

    parser = argparse.ArgumentParser(prog="python -m phri.study", description="phri's user study")
    add_global_options(parser)
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    configure_logging(args.verbose, args.quiet)
    return int(args.run(args))
