"""Fuzzing every public entry point (issue 16): each call returns a finite result or raises a typed
error naming an argument; never a PanicException, an abort, a segfault or a hang. The targets and
the rules are in tests/fuzz_targets.py; each target runs in a child process with a memory limit
(address space) and a time limit, so that a crash or a hang fails its test and names the call.

Derandomised and database-free (the same examples on every run). `PHRI_FUZZ_EXAMPLES` sets the
examples per target (default 200: about 45 s for the 37 targets in `make test` on the shared 2-core machine);
e.g. ``PHRI_FUZZ_EXAMPLES=2000 pytest tests/test_fuzz.py`` for a long run.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("hypothesis")  # a test dependency (pyproject's test extra, the Makefile)

from fuzz_targets import TARGETS  # noqa: E402

EXAMPLES = int(os.environ.get("PHRI_FUZZ_EXAMPLES", "200"))
#: Address space of a target's process [bytes]: a size that is not bounded shows as a MemoryError
#: or an abort here, not as the machine swapping.
MEMORY_LIMIT = 3 << 30
#: Wall time of a target's process [s]; it grows with the examples asked for.
TIME_LIMIT = 60 + 2.0 * EXAMPLES


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


@pytest.mark.parametrize("target", sorted(TARGETS))
def test_fuzz(target: str) -> None:
    script = Path(__file__).with_name("fuzz_targets.py")
    env = {**os.environ, "PYTHONPATH": str(script.parent), "RAYON_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    try:
        done = subprocess.run(
            [sys.executable, str(script), target, str(EXAMPLES)],
            capture_output=True,
            text=True,
            timeout=TIME_LIMIT,
            env=env,
            preexec_fn=_limit_memory,  # noqa: PLW1509 - no threads are started before it
        )
    except subprocess.TimeoutExpired as e:
        calls = [
            line
            for line in (e.stderr or b"").decode(errors="replace").splitlines()
            if line.startswith("CALL")
        ]
        pytest.fail(f"{target}: no answer within {TIME_LIMIT} s (a hang); the last call: {calls[-1:]}")
    if done.returncode != 0:
        lines = done.stderr.splitlines()
        calls = [line for line in lines if line.startswith("CALL")]
        how = (
            f"killed by signal {-done.returncode}"
            if done.returncode < 0
            else f"exit status {done.returncode}"
        )
        report = "\n".join(line for line in lines if not line.startswith("CALL"))[-6000:]
        pytest.fail(f"{target}: {how}; the last call: {calls[-1:]}\n{report}")
