"""``phri study``: runs (or resumes) a study into a folder, with a progress bar."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from phri._extras import check, require
from phri.exceptions import InvalidParameterError
from phri.sim.episode import SIMULATORS
from phri.study.parallel import Backend, check_backend, make_backend
from phri.study.protocol import EpisodeSpec, StudyConfig
from phri.study.results import ResultStore

__all__ = ["StudyRun", "run_study"]

#: results.parquet is refreshed after this many episodes (results.csv after every one).
EXPORT_EVERY = 16


@dataclass
class StudyRun:
    """What a call to :func:`run_study` did."""

    run_dir: Path
    config: StudyConfig
    #: Episodes of the study, episodes done before this call, episodes run by this call.
    total: int
    resumed: int
    ran: int
    #: True when every episode of the study has its row.
    complete: bool
    #: Wall-clock time of this call [s].
    elapsed: float
    backend: str
    workers: int

    @property
    def done(self) -> int:
        """Episodes recorded: those resumed from an earlier run plus those run now."""
        return self.resumed + self.ran


def run_study(
    run_dir: str | Path,
    config: StudyConfig | None = None,
    *,
    backend: str = "process",
    workers: int | None = None,
    address: str | None = None,
    max_episodes: int | None = None,
    progress: bool = True,
    on_episode: Callable[[EpisodeSpec, dict[str, Any]], None] | None = None,
    between_strategies: Callable[[int, str], None] | None = None,
    answered: Callable[[int, str], bool] | None = None,
    allow_version_change: bool = False,
    runner: Callable[[StudyConfig, int], Backend] | None = None,
    simulator: str | None = None,
) -> StudyRun:
    """Runs the study `config` into `run_dir`, or resumes it: episodes already in results.csv are
    kept and skipped. With `config` None the folder's own study is resumed (or the default study is
    started in a new folder).

    `max_episodes` stops after that many new episodes (the rest is left for a later run);
    `on_episode(spec, row)` is called after each episode is recorded (raising from it stops the study,
    keeping everything recorded); `between_strategies(participant, strategy)` is called after a
    participant's last episode with a strategy (for the questionnaire: runs serially, in session order).
    With `answered(participant, strategy)` (is that block's questionnaire in?), it is first called for
    every block finished before this call and not answered yet (a questionnaire lost to an
    interruption is asked on resume), and not for answered blocks.

    `runner(config, log_width)`, if given, makes what runs the episodes instead of `backend` (which
    then only names it): the live study's runner on a real arm (:mod:`phri.study.live`), which runs
    serially in this process, so the questionnaire hooks work with it.

    `workers` must be >= 1 (None: the CPUs available; for backend "ray", the Ray cluster's CPUs). A
    folder started with another phri version is refused (:class:`~phri.study.errors.StudyMismatchError`)
    unless `allow_version_change`. `simulator` (one of :data:`phri.sim.episode.SIMULATORS`; None:
    the config's, "native" by default) simulates the episodes; it is not part of the study, so a
    study may be resumed on another.
    """
    # Before the folder is touched.
    _check_arguments(backend, workers, max_episodes, between_strategies, custom=runner is not None)
    if simulator is None and config is not None:
        simulator = config.simulator  # not saved with the study: a resumed folder's config lacks it
    if simulator is not None and simulator not in SIMULATORS:
        raise InvalidParameterError(f"simulator must be one of {SIMULATORS}, got {simulator!r}")
    began = time.perf_counter()
    store = ResultStore.open(run_dir, config, allow_version_change=allow_version_change)
    config = store.config
    if simulator is not None:
        config = dataclasses.replace(config, simulator=simulator)
    try:
        if between_strategies is not None and answered is not None:
            for participant, strategy in _finished_blocks(store):
                if not answered(participant, strategy):
                    between_strategies(participant, strategy)
        pending = store.pending()
        resumed = len(store.rows)
        if max_episodes is not None:
            pending = pending[:max_episodes]
        ran = 0
        if pending:
            episodes = (
                runner(config, store.log_width)
                if runner is not None
                else make_backend(backend, config, workers, store.log_width, address)
            )
            try:
                ran = _run_pending(store, episodes, pending, resumed, progress, backend, on_episode,
                                   between_strategies, answered)  # fmt: skip
            finally:
                episodes.close()
                store.export()
        store.export(sort_csv=store.complete)
        workers_used = episodes.workers if pending else 0
        return StudyRun(
            Path(run_dir), config, len(store.specs), resumed, ran, store.complete,
            time.perf_counter() - began, backend, workers_used,
        )  # fmt: skip
    finally:
        store.close()


def _check_arguments(
    backend: str,
    workers: int | None,
    max_episodes: int | None,
    between_strategies: Callable[[int, str], None] | None,
    custom: bool = False,
) -> None:
    """Refuses run_study arguments that cannot work, with a typed error naming the argument.
    `custom`: a runner of the caller's runs the episodes (serially; `backend` only names it)."""
    if max_episodes is not None and max_episodes < 0:
        raise InvalidParameterError(f"max_episodes must be >= 0, got {max_episodes}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InvalidParameterError(
            f"workers must be an integer >= 1 (leave it out for the CPUs available), got {workers!r}"
        )
    if custom:
        check(("pandas", "tqdm"), "a study")  # the results table and the progress bar
        return
    if between_strategies is not None and backend != "serial":
        raise InvalidParameterError("between_strategies (the questionnaire) needs backend='serial'")
    check_backend(backend)


def _run_pending(
    store: ResultStore,
    runner: Backend,
    pending: list[EpisodeSpec],
    resumed: int,
    progress: bool,
    backend: str,
    on_episode: Callable[[EpisodeSpec, dict[str, Any]], None] | None,
    between_strategies: Callable[[int, str], None] | None,
    answered: Callable[[int, str], bool] | None,
) -> int:
    """Runs `pending` on `runner`, recording each outcome as it arrives; returns how many ran."""
    ran = 0
    last_of_block = _block_ends(store.specs)
    bar = _progress_bar(len(store.specs), resumed, progress, backend, runner.workers)
    try:
        for outcome in runner.run(pending):
            store.record(outcome.spec, outcome.row, outcome.log)
            ran += 1
            bar.update(1)
            if ran % EXPORT_EVERY == 0:
                store.export()
            if on_episode is not None:
                on_episode(outcome.spec, outcome.row)
            block = (outcome.spec.participant, outcome.spec.strategy)
            if (
                between_strategies is not None
                and outcome.spec.key in last_of_block
                and (answered is None or not answered(*block))
            ):
                bar.clear()
                between_strategies(*block)
    finally:
        bar.close()
    return ran


def _finished_blocks(store: ResultStore) -> list[tuple[int, str]]:
    """The (participant, strategy) blocks whose every episode has its row, in session order."""
    missing = {(s.participant, s.strategy) for s in store.pending()}
    blocks = dict.fromkeys((s.participant, s.strategy) for s in store.specs)
    return [b for b in blocks if b not in missing]


def _block_ends(specs: list[EpisodeSpec]) -> set[tuple[int, str, str, int]]:
    """Keys of each (participant, strategy) block's last episode in session order."""
    last: dict[tuple[int, str], EpisodeSpec] = {}
    for s in specs:
        last[(s.participant, s.strategy)] = s
    return {s.key for s in last.values()}


def _progress_bar(total: int, initial: int, enabled: bool, backend: str, workers: int) -> Any:
    """A tqdm bar on stderr, shown only if `enabled` and stderr is a terminal (disable=None): no
    carriage returns in a log file."""
    tqdm = require("tqdm", __name__).tqdm
    return tqdm(
        total=total, initial=initial, disable=None if enabled else True, unit="episode", dynamic_ncols=True,
        desc=f"study ({backend}, {workers} worker{'s' if workers != 1 else ''})", smoothing=0.1,
    )  # fmt: skip
