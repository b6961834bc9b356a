"""franky-sim's FR3 server in a subprocess on a loopback address, for tests: pylibfranka holds the
GIL while it blocks, so the server cannot run in the test's own process."""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time
from collections.abc import Iterator

SERVER = """
import sys
import franky_sim
from franky_sim.mujoco_simulator import MujocoSimulator
with MujocoSimulator(enable_visualization=False) as sim:
    sim.add_robot()
    with franky_sim.SimulationServer(sim, hostname_candidates=[sys.argv[1]]) as server:
        print("ready", flush=True)
        server.run_forever(float(sys.argv[2]))
"""


@contextlib.contextmanager
def franky_server(host: str, realtime: float = 1.0, timeout: float = 60.0) -> Iterator[str]:
    """Runs the server on `host` (a 127.x.y.z address) until the block ends; yields the address once
    it prints ready. The process is always killed."""
    proc = subprocess.Popen(
        [sys.executable, "-c", SERVER, host, str(realtime)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + timeout
        assert proc.stdout is not None
        while True:
            line = proc.stdout.readline()
            if "ready" in line:
                break
            if not line or time.monotonic() > deadline:
                raise RuntimeError(f"franky-sim server on {host} did not start: {line!r}")
        time.sleep(0.5)  # the server binds after printing
        yield host
    finally:
        proc.kill()
        proc.wait(timeout=10)
        if proc.stdout is not None:
            proc.stdout.close()
