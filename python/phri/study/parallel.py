"""Where episodes run: in this process, in a local process pool, or on Ray actors.

Each backend maps episode specs to :class:`~phri.study.runner.Outcome` s and yields them as they
finish. A worker (pool process or Ray actor) holds one :class:`EpisodeRunner`, so one simulator World
and one Planner per task, reused across its episodes. Because an episode's seed comes from what the
episode is (see :mod:`phri.study.protocol`) and the simulator is reset per episode, every backend gives
the same table.

The tasks are loaded and checked once, in this process (the driver), and every worker gets the
:class:`~phri.config.Task` objects: a worker never reads a task file, so a Ray cluster needs no shared
file system, and a node cannot run another version of a file than the one whose checksum the study
folder checked.

Workers are single-threaded for BLAS/OpenMP: the variables of :data:`THREAD_ENV` are in each worker's
environment from its start, so they are set before the worker imports numpy (pool workers are spawned,
not forked, with these variables; Ray actors get them through their runtime environment).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import socket
import threading
import time
from collections import deque
from collections.abc import Iterable, Iterator, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any, Protocol

from phri._extras import NEEDS, check, require
from phri.config import Task
from phri.exceptions import ConnectionLostError, InvalidParameterError
from phri.study.protocol import EpisodeSpec, StudyConfig
from phri.study.runner import EpisodeRunner, Outcome

__all__ = [
    "BACKENDS",
    "THREAD_ENV",
    "Backend",
    "ProcessBackend",
    "RayBackend",
    "SerialBackend",
    "cluster_cpus",
    "driver_tasks",
    "make_backend",
]

#: The backends a study can run its episodes on.
BACKENDS = ("serial", "process", "ray")

#: One thread per worker for every common BLAS/OpenMP runtime.
THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "BLIS_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
    "RAYON_NUM_THREADS": "1",
}


class Backend(Protocol):
    """Runs episodes; `run` yields their outcomes in completion order."""

    workers: int

    def run(self, specs: Iterable[EpisodeSpec]) -> Iterator[Outcome]:
        """Simulates `specs`, yielding each outcome as it finishes."""
        ...

    def close(self) -> None:
        """Stops the workers; idempotent."""
        ...


def default_workers() -> int:
    """The CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return max(1, os.cpu_count() or 1)


def driver_tasks(config: StudyConfig, tasks: Mapping[str, Task] | None = None) -> dict[str, Task]:
    """The tasks a backend hands to its workers: `tasks` (by name, as ``config.load_tasks()`` gives
    them, e.g. those whose checksums the study folder checked) or, if None, loaded from `config` here,
    in the driver."""
    if tasks is None:
        return config.load_tasks()
    if not isinstance(tasks, Mapping) or not all(
        isinstance(t, Task) and t.name == name for name, t in tasks.items()
    ):
        raise InvalidParameterError(
            f"tasks must map each task name to its phri.config.Task (as StudyConfig.load_tasks() does), "
            f"got {tasks!r}"
        )
    return dict(tasks)


class SerialBackend:
    """Episodes one after another in this process (one World)."""

    def __init__(
        self, config: StudyConfig, log_width: int = 2, tasks: Mapping[str, Task] | None = None
    ) -> None:
        self.workers = 1
        self.runner = EpisodeRunner(config, driver_tasks(config, tasks), log_width)

    def run(self, specs: Iterable[EpisodeSpec]) -> Iterator[Outcome]:
        """Simulates `specs` one after the other in this process."""
        for spec in specs:
            yield self.runner.run(spec)

    def close(self) -> None:
        """Closes the simulator."""
        self.runner.close()


# -- process pool ---------------------------------------------------------------------------------

_RUNNER: EpisodeRunner | None = None

#: How often a pool worker checks that the process that started it is still there [s].
ORPHAN_POLL = 0.25


def _exit_when_orphaned(parent: int, poll: float = ORPHAN_POLL) -> None:
    """Ends this worker once `parent` is gone (its parent pid changes when it is reparented).

    A killed study (SIGKILL, or SIGTERM without a handler) cannot shut its pool down; its workers
    would block forever on the pipes that the other workers still hold open. os._exit, not
    sys.exit: the main thread may be blocked in a write that never returns."""
    while os.getppid() == parent:
        time.sleep(poll)
    os._exit(1)


def _init_worker(
    config: StudyConfig, tasks: dict[str, Task], log_width: int, env: dict[str, str], parent: int
) -> None:
    """Pool initializer: starts the orphan watchdog, pins the thread variables (already inherited
    at spawn) and builds the worker's runner with the driver's tasks; the World itself is made on the
    first episode."""
    global _RUNNER
    watchdog = threading.Thread(target=_exit_when_orphaned, args=(parent,), name="phri-orphaned", daemon=True)
    watchdog.start()
    os.environ.update(env)
    _RUNNER = EpisodeRunner(config, tasks, log_width)


def _run_in_worker(spec: EpisodeSpec) -> Outcome:
    assert _RUNNER is not None, "worker not initialised"
    return _RUNNER.run(spec)


def _worker_environment() -> dict[str, str]:
    """This worker's BLAS/OpenMP environment (for tests: proves the pinning reached the worker)."""
    return {k: os.environ.get(k, "") for k in THREAD_ENV}


@contextlib.contextmanager
def _environment(env: dict[str, str]) -> Iterator[None]:
    """Sets `env` in this process while workers are spawned (they inherit it), then restores it."""
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class ProcessBackend:
    """A local pool of `workers` spawned processes (concurrent.futures), each with one World.

    At most two episodes per worker are queued at a time, so an interrupted study wastes little work.
    Each worker exits by itself when this process dies without shutting the pool down."""

    def __init__(
        self,
        config: StudyConfig,
        workers: int | None = None,
        log_width: int = 2,
        tasks: Mapping[str, Task] | None = None,
    ) -> None:
        self.workers = default_workers() if workers is None else workers
        if self.workers < 1:
            raise InvalidParameterError(f"workers must be >= 1, got {self.workers}")
        self.config, self.log_width = config, log_width
        self.tasks = driver_tasks(config, tasks)
        self._pool: ProcessPoolExecutor | None = None

    def _start(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_worker,
                initargs=(self.config, self.tasks, self.log_width, THREAD_ENV, os.getpid()),
            )
        return self._pool

    def run(self, specs: Iterable[EpisodeSpec]) -> Iterator[Outcome]:
        """Simulates `specs` on the worker processes, yielding outcomes in completion order."""
        todo = deque(specs)
        running: set[Future[Outcome]] = set()
        # Workers are spawned lazily by submit(): keep the variables set while submitting.
        with _environment(THREAD_ENV):
            pool = self._start()
            try:
                while todo or running:
                    while todo and len(running) < 2 * self.workers:
                        running.add(pool.submit(_run_in_worker, todo.popleft()))
                    done, running = wait(running, return_when=FIRST_COMPLETED)
                    for future in done:
                        yield future.result()
            finally:
                for future in running:
                    future.cancel()

    def worker_environments(self) -> list[dict[str, str]]:
        """The thread variables each worker sees (one call per worker, for checks)."""
        with _environment(THREAD_ENV):
            pool = self._start()
            return [f.result() for f in [pool.submit(_worker_environment) for _ in range(self.workers)]]

    def close(self) -> None:
        """Shuts the pool down, cancelling the episodes not started; idempotent."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


# -- Ray ------------------------------------------------------------------------------------------


class _RayWorker:
    """The body of a Ray actor: one runner (one World) for the actor's lifetime, with the driver's
    tasks."""

    def __init__(self, config: StudyConfig, tasks: dict[str, Task], log_width: int) -> None:
        self.runner = EpisodeRunner(config, tasks, log_width)

    def run(self, spec: EpisodeSpec) -> Outcome:
        return self.runner.run(spec)

    def environment(self) -> dict[str, str]:
        return _worker_environment()


class RayBackend:
    """`workers` Ray actors, each keeping one simulator; on a cluster with `address` (e.g. "auto"),
    else a local Ray instance with `workers` CPUs (the CPUs available if None). Ray is used as it is
    if this process already joined it.

    `workers` None means one actor per CPU of the Ray instance (``ray.cluster_resources()["CPU"]``,
    at least one): on a cluster, the whole cluster's CPUs, not this machine's. The tasks are the
    driver's (see :func:`driver_tasks`) and logs travel back as bytes: no shared disk needed.

    Ray is the optional extra ``phri[ray]``."""

    def __init__(
        self,
        config: StudyConfig,
        workers: int | None = None,
        log_width: int = 2,
        address: str | None = None,
        tasks: Mapping[str, Task] | None = None,
    ) -> None:
        ray = require("ray", "the 'ray' backend")
        self.ray = ray
        if workers is not None and workers < 1:
            raise InvalidParameterError(f"workers must be >= 1, got {workers}")
        tasks = driver_tasks(config, tasks)  # before Ray starts: a bad task file fails fast
        self._started = False
        if not ray.is_initialized():
            kwargs: dict[str, Any]
            if address:
                _check_answers(address)
                kwargs = {"address": address}
            else:
                kwargs = {"num_cpus": default_workers() if workers is None else workers}
            ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False, **kwargs)
            self._started = True
        self.workers = cluster_cpus(ray) if workers is None else workers
        actor = ray.remote(num_cpus=1)(_RayWorker)
        options = {"runtime_env": {"env_vars": dict(THREAD_ENV)}}
        self.actors: list[Any] = [
            actor.options(**options).remote(config, tasks, log_width) for _ in range(self.workers)
        ]

    def run(self, specs: Iterable[EpisodeSpec]) -> Iterator[Outcome]:
        """Simulates `specs` on the Ray actors, yielding outcomes in completion order."""
        ray = self.ray
        todo = deque(specs)
        idle = deque(a for a in self.actors for _ in range(2))  # two queued episodes per actor
        running: dict[Any, Any] = {}
        try:
            while todo or running:
                while todo and idle:
                    actor = idle.popleft()
                    running[actor.run.remote(todo.popleft())] = actor
                done, _ = ray.wait(list(running), num_returns=1)
                for ref in done:
                    idle.append(running.pop(ref))
                    yield ray.get(ref)
        finally:
            for ref in running:
                ray.cancel(ref)

    def worker_environments(self) -> list[dict[str, str]]:
        """The thread variables each actor sees (one per actor, for checks)."""
        return self.ray.get([a.environment.remote() for a in self.actors])

    def close(self) -> None:
        """Ends the actors."""
        for actor in self.actors:
            self.ray.kill(actor)
        self.actors = []
        if self._started:
            self.ray.shutdown()
            self._started = False


#: How long a Ray cluster's address may take to accept a connection [s].
RAY_CONNECT_TIMEOUT = 10.0


def _check_answers(address: str) -> None:
    """Raises ConnectionLostError naming `address` unless something accepts a TCP connection there
    within RAY_CONNECT_TIMEOUT (Ray itself retries an unreachable address for ever). "auto" and
    addresses without a port are left to Ray."""
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or "://" in address:
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=RAY_CONNECT_TIMEOUT).close()
    except OSError as e:
        raise ConnectionLostError(
            f"address {address!r}: no Ray cluster answers there within {RAY_CONNECT_TIMEOUT:g} s ({e})"
        ) from None


def cluster_cpus(ray: Any) -> int:
    """The CPUs of the Ray instance this process joined (every node's), at least one: an autoscaling
    cluster may have none yet, and one actor is what makes it add a node."""
    return max(1, int(ray.cluster_resources().get("CPU", 0)))


def check_backend(name: str) -> None:
    """Raises if backend `name` is unknown (InvalidParameterError) or cannot run a study here
    (:class:`~phri.exceptions.MissingExtraError`: the simulation, the results table and the progress
    bar come with ``phri[study]``, Ray with ``phri[ray]``); imports none of them."""
    if name not in BACKENDS:
        raise InvalidParameterError(f"backend must be one of {BACKENDS}, got {name!r}")
    check((*NEEDS["a study"], *(("ray",) if name == "ray" else ())), "a study")


def make_backend(
    name: str,
    config: StudyConfig,
    workers: int | None = None,
    log_width: int = 2,
    address: str | None = None,
    tasks: Mapping[str, Task] | None = None,
) -> Backend:
    """A backend by name: "serial", "process" (default for studies) or "ray". Its workers run `tasks`
    (None: the study's tasks, loaded here in the driver; see :func:`driver_tasks`)."""
    if name == "serial":
        return SerialBackend(config, log_width, tasks)
    if name == "process":
        return ProcessBackend(config, workers, log_width, tasks)
    if name == "ray":
        return RayBackend(config, workers, log_width, address, tasks)
    raise InvalidParameterError(f"backend must be one of {BACKENDS}, got {name!r}")
