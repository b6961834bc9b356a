"""franky-sim's simulated FR3 (MuJoCo) serving the libfranka protocol on a loopback address, in its
own process: libfranka's client holds the interpreter while it waits on the network, so a server
in a thread of the client's process would never answer it.

``python -m phri.franka.sim_server --host 127.0.0.2 --realtime 1`` serves until it is stopped;
:class:`SimServer` starts one for a block of code and always stops it.
"""

from __future__ import annotations

import argparse
import ipaddress
import socket
import subprocess
import sys
import threading
import time
from types import TracebackType
from typing import IO

from phri.exceptions import ConnectionLostError, InvalidParameterError

__all__ = ["SimServer", "main"]

#: The line the server prints once it is ticking, followed by its address.
READY = "franky-sim serving the libfranka protocol on"
#: How long the simulator may take to start and open its port [s] (MuJoCo loads the FR3 model).
START_TIMEOUT = 60.0


def check_loopback(host: str) -> str:
    """`host` if it is a loopback address (127.x.y.z): the simulator serves nowhere else."""
    try:
        ok = ipaddress.ip_address(host).is_loopback and ipaddress.ip_address(host).version == 4
    except ValueError:
        ok = False
    if not ok:
        raise InvalidParameterError(f"host must be a loopback address 127.x.y.z, got {host!r}")
    return host


class SimServer:
    """franky-sim on `host` (a loopback address) in a child process, slowed by `realtime` (1: real
    time; 2: each 1 ms tick takes 2 ms of wall time, for loaded machines). Use as a context manager:
    the process is started, waited for until its port answers, and always killed at the end."""

    def __init__(self, host: str, *, realtime: float = 1.0) -> None:
        self.host = check_loopback(host)
        if not (isinstance(realtime, int | float) and 0 < realtime <= 100):
            raise InvalidParameterError(f"realtime must be a slow-down factor in (0, 100], got {realtime!r}")
        self.realtime = float(realtime)
        self.process: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> SimServer:
        from phri.franka.backend import COMMAND_PORT

        command = [
            sys.executable,
            "-m",
            "phri.franka.sim_server",
            "--host",
            self.host,
            "--realtime",
            str(self.realtime),
        ]
        self.process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
        )
        assert self.process.stdout is not None
        # Its output is read until the ready line (a thread: readline has no timeout), then dropped.
        lines: list[str] = []
        ready = threading.Event()

        def drain(stream: IO[bytes]) -> None:
            for raw in stream:
                line = raw.decode(errors="replace").rstrip()
                if not ready.is_set():
                    lines.append(line)
                    if line.startswith(READY):
                        ready.set()

        threading.Thread(target=drain, args=(self.process.stdout,), daemon=True).start()
        deadline = time.monotonic() + START_TIMEOUT
        while not ready.wait(0.1):
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise ConnectionLostError(
                    f"franky-sim on {self.host} did not start within {START_TIMEOUT:g} s: "
                    + " | ".join(lines[-20:])
                )
        try:
            socket.create_connection((self.host, COMMAND_PORT), timeout=5.0).close()
        except OSError as e:
            self.stop()
            raise ConnectionLostError(f"franky-sim on {self.host} does not answer on its port: {e}") from None
        return self

    def stop(self) -> None:
        """Kills the server (idempotent)."""
        process, self.process = self.process, None
        if process is not None:
            if process.poll() is None:
                process.kill()
            process.wait(timeout=10)
            if process.stdout is not None:
                process.stdout.close()

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        self.stop()


def main(argv: list[str] | None = None) -> int:
    """Serves franky-sim's FR3 on ``--host`` (a loopback address) until stopped; prints the ready
    line once clients can connect. Returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m phri.franka.sim_server", description=__doc__)
    parser.add_argument("--host", default="127.0.0.2", help="loopback address to serve on")
    parser.add_argument("--realtime", type=float, default=1.0, help="slow-down factor (1: real time)")
    args = parser.parse_args(argv)
    check_loopback(args.host)
    from phri._extras import require

    franky_sim = require("franky_sim", "the Franka simulator")
    mujoco_simulator = require("franky_sim.mujoco_simulator", "the Franka simulator")

    with mujoco_simulator.MujocoSimulator(enable_visualization=False) as sim:
        sim.add_robot()
        with franky_sim.SimulationServer(sim, hostname_candidates=[args.host]) as server:
            # The loop first, then the line: a client that connects on it finds the server ticking.
            server.run_async(args.realtime)
            time.sleep(0.05)
            print(f"{READY} {args.host}", flush=True)
            try:
                while server.async_thread is not None and server.async_thread.is_alive():
                    server.async_thread.join(0.5)
            except KeyboardInterrupt:
                pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
