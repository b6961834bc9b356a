"""A local Ray instance started for a study listens on loopback only (issue 16 #22)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("ray", reason="Ray is not installed (optional extra phri[ray]); backend 'ray' untested")

# In a fresh process (Ray must not be imported before phri starts it): start the backend, then list
# the TCP sockets that the process and everything it started listen on (/proc, no extra tool).
SCRIPT = textwrap.dedent(
    """
    import os, pathlib, json
    from phri.study import StudyConfig
    from phri.study.parallel import RayBackend

    def tree(root):
        children = {}
        for stat in pathlib.Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
        todo, seen = [root], set()
        while todo:
            pid = todo.pop()
            seen.add(pid)
            todo += children.get(pid, [])
        return seen

    def inodes(pids):
        found = set()
        for pid in pids:
            try:
                for fd in pathlib.Path(f"/proc/{pid}/fd").iterdir():
                    target = os.readlink(fd)
                    if target.startswith("socket:["):
                        found.add(target[8:-1])
            except OSError:
                pass
        return found

    def listening(ours):
        out = []
        for table in ("tcp", "tcp6"):
            for line in pathlib.Path(f"/proc/net/{table}").read_text().splitlines()[1:]:
                f = line.split()
                if f[3] == "0A" and f[9] in ours:  # LISTEN
                    out.append(f[1])
        return out

    config = StudyConfig(participants=1, attempts=1, tasks=("coffee",), familiarization=None)
    backend = RayBackend(config, workers=1)
    try:
        print(json.dumps(listening(inodes(tree(os.getpid())))))
    finally:
        backend.close()
    """
)

# 127.0.0.1 as /proc/net/tcp writes it (little-endian hex), and as an IPv4-mapped IPv6 address.
LOOPBACK = ("0100007F:", "0000000000000000FFFF00000100007F:", "00000000000000000000000001000000:")


@pytest.mark.slow
def test_a_local_ray_instance_listens_on_loopback_only() -> None:
    env = {k: v for k, v in os.environ.items() if k != "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"}
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=180, env=env, check=True
    )
    sockets = __import__("json").loads(done.stdout.strip().splitlines()[-1])
    assert sockets, "found no listening socket of the Ray instance (the check could not fail)"
    exposed = [s for s in sockets if not s.startswith(LOOPBACK)]
    assert not exposed, f"Ray listens beyond loopback: {exposed} (of {sockets})"
