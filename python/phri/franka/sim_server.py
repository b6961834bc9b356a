"""franky-sim's simulated FR3 (MuJoCo) serving the libfranka protocol on a loopback address, with
phri's scene, participant and faults (:mod:`phri.franka.scene_server`), in its own process:
libfranka's client holds the interpreter while it waits on the network, so a server in a thread of
the client's process would never answer it.

``phri sim-server --task table`` (or ``python -m phri.franka.sim_server``) serves until Ctrl-C;
:class:`SimServer` starts one for a block of code and always stops it.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING

from phri._validate import check_loopback
from phri.exceptions import ConfigError, ConnectionLostError, InvalidParameterError

if TYPE_CHECKING:
    from phri.config import Task

__all__ = ["DEFAULT_HOST", "READY", "SimServer", "add_arguments", "check_loopback", "fr3_task", "main"]

#: The line the server prints once it is ticking, followed by its address.
READY = "franky-sim serving the libfranka protocol on"
#: The simulator's default address: loopback, and not 127.0.0.1, which other local services use.
DEFAULT_HOST = "127.0.0.2"
#: How long the simulator may take to start and open its port [s] (MuJoCo loads the FR3 model and
#: the participant's desired plan is made).
START_TIMEOUT = 60.0
#: The server's output lines a SimServer keeps (the latest).
KEPT_LINES = 1000
#: How long stopping a SimServer waits for the rest of the child's output to be read [s].
DRAIN_WAIT = 5.0


def check_realtime(realtime: object) -> float:
    """`realtime` as a slow-down factor in (0, 100]."""
    if not (isinstance(realtime, int | float) and not isinstance(realtime, bool) and 0 < realtime <= 100):
        raise InvalidParameterError(f"realtime must be a slow-down factor in (0, 100], got {realtime!r}")
    return float(realtime)


def check_duration(duration: object) -> float:
    """`duration` as a task duration override [s]: finite and > 0."""
    if isinstance(duration, bool) or not (
        isinstance(duration, int | float) and math.isfinite(duration) and duration > 0
    ):
        raise InvalidParameterError(f"duration must be a finite time > 0 s, got {duration!r}")
    return float(duration)


def fr3_task(name_or_path: str | Path) -> Task:
    """The FR3 task `name_or_path`: a shipped FR3 task by its name with or without the ``fr3_``
    prefix (``table`` is ``fr3_table``), or a task file; a task posed for another robot is a
    ConfigError."""
    from phri.config import load_task, task_names

    text = str(name_or_path)
    is_file = text.endswith(".toml") or os.path.lexists(text)
    if not is_file and f"fr3_{text}" in task_names():
        text = f"fr3_{text}"
    task = load_task(text)
    if task.robot != "fr3":
        fr3 = ", ".join(n for n in task_names() if n.startswith("fr3_"))
        raise ConfigError(
            f"task: {task.source} is posed for robot '{task.robot}', but the simulator is an FR3; "
            f'use an FR3 task ({fr3}) or a task file with robot = "fr3"'
        )
    return task


class SimServer:
    """phri's scene server on `host` (a loopback address) in a child process, slowed by `realtime`
    (1: real time; 2: each 1 ms tick takes 2 ms of wall time, for loaded machines). `task` (an FR3
    task name or file; None: the bare FR3) brings its scene and the participant seeded `seed`, drawn
    from `population` (a population file or shipped name; None: phri's default; `person=False`: the
    scene without them); `duration` [s] overrides the task's (the person's desired behaviour is the
    plan for it, so a client running the task shortened must shorten it here too); `faults` is a
    schedule (``KIND[:ARG][@T]`` strings, see :mod:`phri.franka.faults`), and :meth:`inject` sends
    one through the control channel.

    Use as a context manager: the process is started, waited for until its port answers, and always
    killed at the end."""

    def __init__(
        self,
        host: str = DEFAULT_HOST,
        *,
        realtime: float = 1.0,
        task: str | Path | None = None,
        seed: int = 0,
        person: bool = True,
        population: str | Path | None = None,
        duration: float | None = None,
        faults: Sequence[str] = (),
        log_protocol: bool = False,
    ) -> None:
        from phri.franka.faults import Fault

        self.host = check_loopback(host)
        self.realtime = check_realtime(realtime)
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise InvalidParameterError(f"seed must be an integer >= 0, got {seed!r}")
        if task is not None:
            fr3_task(task)  # a missing or wrong task is a ConfigError here, not a dead child
        if population is not None:
            from phri.sim.participant import load_population

            load_population(population)  # likewise a bad population file
        # A Path is a file (the child takes a bare word such as "lab" for a shipped name).
        self.population = str(population.absolute()) if isinstance(population, Path) else population
        self.duration = None if duration is None else check_duration(duration)
        self.task, self.seed, self.person, self.log_protocol = task, seed, person, log_protocol
        self.faults = [Fault.parse(f).spec() for f in faults]
        self.process: subprocess.Popen[bytes] | None = None
        #: The server's output lines (the latest KEPT_LINES): its ready line, injected faults.
        self.lines: collections.deque[str] = collections.deque(maxlen=KEPT_LINES)
        self._drain: threading.Thread | None = None

    def command(self) -> list[str]:
        """The child's command line."""
        command = [sys.executable, "-m", "phri.franka.sim_server", "--host", self.host]
        command += ["--realtime", str(self.realtime), "--seed", str(self.seed), "--control-stdin"]
        if self.task is not None:
            command += ["--task", str(self.task)]
        if self.duration is not None:
            command += ["--duration", repr(self.duration)]
        if self.population is not None:
            command += ["--population", self.population]
        if not self.person:
            command.append("--no-person")
        if self.log_protocol:
            command.append("--log-protocol")
        for fault in self.faults:
            command += ["--fault", fault]
        return command

    def __enter__(self) -> SimServer:
        self.process = subprocess.Popen(
            self.command(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.PIPE
        )
        assert self.process.stdout is not None
        # Its output is read in a thread (readline has no timeout), kept for inspection.
        ready = threading.Event()

        def drain(stream: IO[bytes]) -> None:
            try:
                for raw in stream:
                    line = raw.decode(errors="replace").rstrip()
                    self.lines.append(line)
                    if line.startswith(READY):
                        ready.set()
            except (ValueError, OSError):
                pass  # stop() closed the stream: a child that outlived DRAIN_WAIT is dead now

        self._drain = threading.Thread(target=drain, args=(self.process.stdout,), daemon=True)
        self._drain.start()
        try:
            self._wait_ready(ready)
        except BaseException:
            # __exit__ does not run when __enter__ fails: whatever failed (a timeout, Ctrl-C while
            # waiting), the child must not outlive it.
            self.stop()
            raise
        return self

    def _wait_ready(self, ready: threading.Event) -> None:
        """Waits until the child printed its ready line and its port answers, else raises
        ConnectionLostError."""
        from phri.franka.backend import COMMAND_PORT

        assert self.process is not None
        deadline = time.monotonic() + START_TIMEOUT
        while not ready.wait(0.1):
            status = self.process.poll()
            if status is not None or time.monotonic() > deadline:
                what = (
                    f"exited with status {status}"
                    if status is not None
                    else (f"did not start within {START_TIMEOUT:g} s")
                )
                raise ConnectionLostError(
                    f"franky-sim on {self.host} {what}: " + " | ".join(list(self.lines)[-20:])
                )
        try:
            socket.create_connection((self.host, COMMAND_PORT), timeout=5.0).close()
        except OSError as e:
            raise ConnectionLostError(f"franky-sim on {self.host} does not answer on its port: {e}") from None

    def inject(self, fault: str) -> None:
        """Sends `fault` (``KIND[:ARG][@T]``) through the control channel; the server injects it at
        its next tick (at robot time T of the torque-control motion if timed)."""
        from phri.franka.faults import Fault

        spec = Fault.parse(fault).spec()
        process = self.process
        if process is None or process.stdin is None or process.poll() is not None:
            raise ConnectionLostError(f"franky-sim on {self.host} is not running")
        process.stdin.write(spec.encode() + b"\n")
        process.stdin.flush()

    def stop(self) -> None:
        """Kills the server (idempotent)."""
        process, self.process = self.process, None
        if process is not None:
            if process.poll() is None:
                process.kill()
            process.wait(timeout=10)
            # The output read so far is kept: the reader ends at the end of the stream, which comes
            # once the child is gone; closing it under the reader would end it with an error.
            if self._drain is not None:
                self._drain.join(DRAIN_WAIT)
                self._drain = None
            for stream in (process.stdout, process.stdin):
                if stream is not None:
                    try:
                        stream.close()
                    except OSError:
                        pass

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        self.stop()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The scene server's options (``phri sim-server`` and ``python -m phri.franka.sim_server``)."""
    parser.add_argument("--task", default=None,
                        help="FR3 task name (table, laptop, human, coffee, or fr3_*) or task file; "
                        "default: the bare FR3, no scene")  # fmt: skip
    parser.add_argument("--host", default=DEFAULT_HOST,
                        help=f"loopback address to serve on (127.x.y.z; default {DEFAULT_HOST})")  # fmt: skip
    parser.add_argument("--realtime", type=float, default=1.0,
                        help="slow-down: 1 real time, 2: a 1 ms tick takes 2 ms (default 1)")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated participant (default 0)")
    parser.add_argument("--duration", type=float, default=None,
                        help="override the task's duration [s] (the person's plan lasts as long; "
                        "give the client the same override)")  # fmt: skip
    parser.add_argument("--population", default=None,
                        help="population the participant is drawn from: a TOML file or a shipped name "
                        "(default: default; see `phri study --population`)")  # fmt: skip
    parser.add_argument("--no-person", action="store_true", help="the scene without the participant")
    parser.add_argument("--fault", action="append", default=[], metavar="KIND[:ARG][@T]",
                        help="inject a fault (repeatable): reflex[:ERRORS], user_stop[:S], "
                        "nan[:q|dq|tau_ext], late:N, stall:S, drop; @T: robot time [s] into the "
                        "torque-control motion")  # fmt: skip
    parser.add_argument("--log-protocol", action="store_true",
                        help="log franky-sim's protocol events (connections, commands)")  # fmt: skip
    parser.add_argument("--control-stdin", action="store_true",
                        help="read faults, one per line, from stdin (the control channel); the "
                        "server stops when stdin closes")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    """Serves as `args` (from :func:`add_arguments`) say until Ctrl-C."""
    from phri.franka.faults import Fault
    from phri.franka.scene_server import serve

    check_loopback(args.host)
    realtime = check_realtime(args.realtime)
    if args.seed < 0:
        raise InvalidParameterError(f"--seed must be >= 0, got {args.seed}")
    faults = [Fault.parse(f) for f in args.fault]
    if args.log_protocol:
        import logging

        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(relativeCreated)8.0f ms %(name)s: %(message)s"))
        logging.getLogger("franky_sim").addHandler(handler)
        logging.getLogger("franky_sim").setLevel(logging.DEBUG)
    task = fr3_task(args.task) if args.task is not None else None
    population = None
    if args.population is not None:
        from phri.sim.participant import load_population

        population = load_population(args.population)  # a bad file: its error, before serving
    if args.duration is not None:
        if task is None:
            raise InvalidParameterError("--duration needs --task (the bare FR3 has no task to shorten)")
        task = dataclasses.replace(task, duration=check_duration(args.duration))
    # Ctrl-C stops the server, also when it was started with SIGINT ignored (a shell starts a
    # background job so, and Python then installs no handler: Ctrl-C would be ignored for good).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    serve(
        args.host,
        task=task,
        realtime=realtime,
        seed=args.seed,
        person=not args.no_person,
        population=population,
        faults=faults,
        control=sys.stdin if args.control_stdin else None,
        report=lambda line: print(line, flush=True),  # the ready line SimServer and users wait for
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    """Serves franky-sim's FR3 on ``--host`` (a loopback address) until stopped; prints the ready
    line once clients can connect. Returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m phri.franka.sim_server", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
