"""Runs episodes of a study: one simulator World, reused across episodes, and one Planner per task.

Every backend (serial, process pool, Ray) wraps an :class:`EpisodeRunner`; what comes back is an
:class:`Outcome` — the table row and the episode's log as the bytes of its .npz, made in memory — so
that the process that owns the study folder is the only one that writes to it, once (and a cluster
needs no shared file system). Likewise the tasks: the process that starts the study loads and checks
the task files once and hands the :class:`~phri.config.Task` objects to every runner, so no worker
reads a task file.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from phri.config import Task
from phri.exceptions import SafetyStopError, SimulationError
from phri.sim.episode import Planner, encode_log, episode_failure, simulate_episode
from phri.sim.participant import ParticipantParams
from phri.sim.world import World
from phri.study.protocol import EpisodeSpec, StudyConfig, participant_params
from phri.study.results import episode_row, failed_row

__all__ = ["EpisodeRunner", "Outcome"]


@dataclass
class Outcome:
    """One finished episode: its row of the results table and its compressed .npz log (the bytes of the
    file, made in memory; empty: no log)."""

    spec: EpisodeSpec
    row: dict[str, object]
    log: bytes


class EpisodeRunner:
    """Runs any episode of `config` with its `tasks` (by name, as ``config.load_tasks()`` gives them,
    loaded by the caller: the runner reads no task file); the World and the Planners are made once and
    reused."""

    def __init__(self, config: StudyConfig, tasks: Mapping[str, Task], log_width: int = 2) -> None:
        self.config = config
        self.tasks = dict(tasks)
        self.log_width = log_width
        self._world: World | None = None
        self._planners: dict[str, Planner] = {}
        self._participants: dict[int, ParticipantParams] = {}

    @property
    def world(self) -> World:
        """The simulator, started on first use."""
        if self._world is None:
            self._world = World()
        return self._world

    def planner(self, task: str) -> Planner:
        """The planner of `task`, made once."""
        if task not in self._planners:
            self._planners[task] = Planner(self.tasks[task], self.world)
        return self._planners[task]

    def participant(self, p: int) -> ParticipantParams:
        """Participant `p`'s parameters, drawn from the study seed once."""
        if p not in self._participants:
            self._participants[p] = participant_params(self.config.seed, p, self.config.population)
        return self._participants[p]

    def run(self, spec: EpisodeSpec) -> Outcome:
        """Simulates `spec`. A :class:`~phri.exceptions.SimulationError`, or a safety stop of the arm
        (:class:`~phri.exceptions.SafetyStopError`), becomes a row with status "failed" (metrics
        NaN, the message in `error`) and the partial log; other errors propagate."""
        task = self.tasks[spec.task]
        name = spec.log_name(self.log_width)
        try:
            result, error = simulate_episode(
                task, self.world, self.participant(spec.participant).for_attempt(spec.attempt),
                self.config.episode_config(spec.strategy), seed=spec.seed, planner=self.planner(spec.task),
            )  # fmt: skip
        except SimulationError as e:  # before the simulation started: no log
            return Outcome(spec, failed_row(spec, str(e), ""), b"")
        if error is not None and not isinstance(error, SimulationError | SafetyStopError):
            raise error
        log = f"logs/{name}"
        if isinstance(error, SimulationError | SafetyStopError):
            row = failed_row(spec, str(episode_failure(task.name, spec.strategy, error, log)), log)
        else:
            row = episode_row(spec, result, task, log)
        return Outcome(spec, row, encode_log(result.log_arrays))

    def close(self) -> None:
        """Closes the simulator and forgets the planners."""
        if self._world is not None:
            self._world.close()
            self._world = None
        self._planners.clear()
