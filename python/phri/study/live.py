"""The study with real people on a real arm, as the paper ran it: ``phri study RUN --robot fr3 --host
ADDR --live``.

:class:`LiveRunner` runs the study's episodes one after another on the Franka at an address, with
the experimenter at the terminal: for each episode it announces the participant, the strategy, the
task and the attempt, waits for the go (Enter; ``q`` pauses the study and exits cleanly), moves the
arm to the task's start pose and runs the episode (:class:`phri.franka.episode.FrankaEpisode`: the
person's push is what the robot measures). It stands beside the simulated runner
(:class:`phri.study.runner.EpisodeRunner`) and gives what it gives: a row of the results table and
the episode's log, so that everything else (the study folder, resuming, the questionnaire after each
strategy, ``phri report``) is the simulated study's.

An episode the arm stopped (a safety stop, a reflex, a lost connection) is reported at once; the
experimenter records it as failed (its row says why, its log is kept), runs it again (the stopped
attempt's log is kept beside, ``logs/<episode>.stopped-N.npz``) or pauses. An episode that never
started (nothing answers, the move to the start pose refused, or stopped: its log is kept as
``logs/<episode>.move-N.npz``) is never recorded: try again, or pause and bring the arm closer by
hand.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path

from phri.config import Task
from phri.exceptions import PhriError
from phri.franka.episode import CONNECT_TIMEOUT, FrankaEpisode, FrankaOutcome, check_task_robot
from phri.franka.move import MAX_MOVE, MOVE_SPEED
from phri.sim.episode import Planner, encode_log, episode_failure
from phri.study.protocol import EpisodeSpec, StudyConfig
from phri.study.results import LOGS, episode_row, failed_row
from phri.study.runner import Outcome

__all__ = ["FR3_TASKS", "LiveRunner", "StudyPaused", "live_tasks"]

#: The study's tasks posed for the FR3, familiarization first (the simulated study's order).
FR3_TASKS = ("fr3_human", "fr3_coffee", "fr3_table", "fr3_laptop")

#: What the experimenter types at the go prompt to pause, and to run an episode again.
PAUSE = "q"
AGAIN = "r"


class StudyPaused(Exception):
    """The experimenter paused the study at a prompt; every recorded episode is kept and the same
    command resumes it."""


def live_tasks(config: StudyConfig, robot: str) -> dict[str, Task]:
    """The study's tasks (``config.load_tasks()``), each checked to be posed for `robot`."""
    tasks = config.load_tasks()
    for task in tasks.values():
        check_task_robot(task, robot)
    return tasks


class LiveRunner:
    """Runs a study's episodes on the Franka at `host` with the experimenter at the terminal
    (`read` asks, `write` tells: the terminal's input and print by default). A
    :class:`phri.study.parallel.Backend` with one worker.

    `run_dir` is the study folder (for the logs of stopped attempts run again); `connect_timeout`,
    `move_speed`, `max_move` as for :class:`phri.franka.episode.FrankaEpisode`."""

    workers = 1

    def __init__(
        self,
        config: StudyConfig,
        tasks: Mapping[str, Task],
        log_width: int,
        *,
        host: str,
        run_dir: Path,
        robot: str = "fr3",
        connect_timeout: float = CONNECT_TIMEOUT,
        move_speed: float = MOVE_SPEED,
        max_move: float = MAX_MOVE,
        read: Callable[[str], str] = input,
        write: Callable[[str], object] = print,
    ) -> None:
        for task in tasks.values():
            check_task_robot(task, robot)
        self.config, self.tasks, self.log_width = config, dict(tasks), log_width
        self.host, self.run_dir, self.robot = host, Path(run_dir), robot
        self.connect_timeout, self.move_speed, self.max_move = connect_timeout, move_speed, max_move
        self.read, self.write = read, write
        self._planners: dict[str, Planner] = {}
        self._total = config.episodes

    def planner(self, task: str) -> Planner:
        """The planner of `task` (a key of the study's tasks), made once and reused by its episodes."""
        if task not in self._planners:
            from phri._phri import Robot

            t = self.tasks[task]
            self._planners[task] = Planner(t, Robot.from_description(t.robot))
        return self._planners[task]

    # -- the protocol ------------------------------------------------------------------------------

    def run(self, specs: Iterable[EpisodeSpec]) -> Iterator[Outcome]:
        """Each of `specs` in turn (:meth:`episode`), its outcome as it is recorded."""
        for spec in specs:
            yield self.episode(spec)

    def episode(self, spec: EpisodeSpec) -> Outcome:
        """Announces `spec`, waits for the go, and runs it until it is recorded (done or failed) or
        the experimenter pauses (:class:`StudyPaused`)."""
        task = self.tasks[spec.task]
        attempts = self.config.attempts
        strategies = len(self.config.strategies)
        self.write(
            f"\nEpisode {spec.index + 1} of {self._total}: participant {spec.participant}, strategy "
            f"'{spec.strategy}' ({spec.order} of {strategies}), task {task.name} ({task.title}), "
            f"attempt {spec.attempt} of {attempts}"
        )
        self._ask_go("Enter when the participant is ready (the arm moves to the start, the episode runs)")
        stopped = 0
        while True:
            outcome, problem = self._attempt(spec, task)
            if problem is None:
                return outcome
            if isinstance(problem, _NotStarted):
                self.write(f"The episode did not start: {problem}")
                self._ask_go("Enter to try again")
                continue
            self.write(f"The episode was stopped: {problem}")
            answer = self._ask(
                f"Enter: record it as failed and go on; {AGAIN}: run it again; {PAUSE}: pause", (AGAIN,)
            )
            if answer != AGAIN:
                return outcome
            stopped += 1
            self._keep_stopped(spec, outcome, stopped)

    def _attempt(self, spec: EpisodeSpec, task: Task) -> tuple[Outcome, BaseException | None]:
        """Runs the episode once: its outcome (a row and the log), and what stopped it (None: it
        ran to its end). An episode that never started (nothing answers, the move refused or
        stopped, control refused) is a _NotStarted, with no outcome to record."""
        episode = FrankaEpisode(
            self.host, task, self.config.episode_config(spec.strategy), planner=self.planner(spec.task),
            connect_timeout=self.connect_timeout, move_speed=self.move_speed, max_move=self.max_move,
        )  # fmt: skip
        self.write("Moving the arm to the start pose, then the episode runs ...")
        try:
            franka = episode.run()
        except PhriError as e:  # before anything moved: no answer, the move refused
            return Outcome(spec, {}, b""), _NotStarted(str(e))
        if franka.result is None:
            if franka.move_result is not None and franka.move_result.ticks:
                self._keep_move(spec, franka)
            return Outcome(spec, {}, b""), _NotStarted(str(franka.error))
        self._report(franka)
        name = spec.log_name(self.log_width)
        log = f"{LOGS}/{name}"
        data = encode_log(franka.log_arrays)
        if franka.error is None:
            return Outcome(spec, episode_row(spec, franka.result, task, log), data), None
        error = franka.error
        if not isinstance(error, PhriError):
            raise error  # a bug, not the arm: the log so far is not a result
        message = str(episode_failure(task.name, spec.strategy, error, log))
        return Outcome(spec, failed_row(spec, message, log), data), error

    def _report(self, franka: FrankaOutcome) -> None:
        r = franka.result
        assert r is not None
        self.write(
            f"  effort {r.effort:.1f} N·m, interaction time {r.interaction_time:.2f} s; "
            f"{franka.ticks} ticks, {franka.late_ticks} late on the robot's clock"
        )

    def _keep_stopped(self, spec: EpisodeSpec, outcome: Outcome, n: int) -> None:
        """Keeps the log of a stopped attempt that is run again (never overwritten)."""
        from phri.atomic import write_atomic

        if outcome.log:
            stem = spec.log_name(self.log_width).removesuffix(".npz")
            write_atomic(self.run_dir / LOGS / f"{stem}.stopped-{n}.npz", outcome.log, overwrite=False)

    def _keep_move(self, spec: EpisodeSpec, franka: FrankaOutcome) -> None:
        """Keeps the log of a move to the start that was stopped (beside the episodes' logs)."""
        from phri.atomic import write_atomic

        stem = spec.log_name(self.log_width).removesuffix(".npz")
        logs = self.run_dir / LOGS
        k = 1
        while (logs / f"{stem}.move-{k}.npz").exists():
            k += 1
        write_atomic(logs / f"{stem}.move-{k}.npz", encode_log(franka.log_arrays), overwrite=False)

    # -- the terminal ------------------------------------------------------------------------------

    def _ask(self, prompt: str, choices: tuple[str, ...] = ()) -> str:
        """The experimenter's answer: "" (Enter) or one of `choices`; PAUSE (or the end of the
        input) pauses the study."""
        while True:
            try:
                answer = self.read(f"{prompt}: ").strip().lower()
            except EOFError:
                raise StudyPaused("the terminal's input ended") from None
            if answer == PAUSE:
                raise StudyPaused("paused at the experimenter's request")
            if answer == "" or answer in choices:
                return answer
            options = ", ".join(["Enter", *choices, PAUSE])
            self.write(f"   please type one of: {options}")

    def _ask_go(self, prompt: str) -> None:
        self._ask(f"{prompt} ({PAUSE}: pause)")

    def close(self) -> None:
        """Drops the planners made for the study's tasks (each episode connects to the arm itself)."""
        self._planners.clear()


class _NotStarted(Exception):
    """The episode did not start (nothing answers, the move to the start pose was refused or did
    not finish, control refused): nothing to record."""
