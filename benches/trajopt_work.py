"""Instructions per cold trajectory solve, N = 100 against N = 31, counted under callgrind.

Times on a shared machine move by ±40% between (and within) runs; instruction counts do not. For each
study task this runs `trajopt_work` (benches/trajopt_work.rs) under `valgrind --tool=callgrind` with 1
and 1 + REPS solves and takes the difference, so the count excludes start-up (URDF parsing), for
N = 31 and for N = 100 with the weights rescaled from 31 waypoints and unscaled.

    python benches/trajopt_work.py [--reps 5]      (or `make bench-trajopt-work`; needs valgrind)
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BINARY = ROOT / "target" / "release" / "trajopt_work"
TASKS = ("human", "coffee", "table", "laptop")


def instructions(*args: str) -> int:
    out = subprocess.run(
        ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", str(BINARY), *args],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    match = re.search(r"Collected : (\d+)", out.stderr)
    if match is None:
        raise RuntimeError(f"no instruction count from callgrind:\n{out.stderr}")
    return int(match.group(1))


def per_solve(n: int, task: str, reps: int, *extra: str) -> float:
    return (
        instructions(str(n), task, str(1 + reps), *extra) - instructions(str(n), task, "1", *extra)
    ) / reps


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=5, help="solves counted per case")
    args = ap.parse_args()
    if shutil.which("valgrind") is None:
        print("valgrind is not installed (apt-get install valgrind)", file=sys.stderr)
        return 1
    subprocess.run(
        ["cargo", "build", "--release", "-q", "-p", "phri_benches", "--bin", "trajopt_work"],
        cwd=ROOT,
        check=True,
    )
    print(
        "10⁶ instructions per cold solve; N = 100 with the weights rescaled from 31 waypoints, then unscaled"
    )
    print(f"{'task':<8} {'N=31':>10} {'N=100':>10} {'ratio':>6} {'unscaled':>10} {'ratio':>6}")
    for task in TASKS:
        base = per_solve(31, task, args.reps)
        fine = per_solve(100, task, args.reps)
        raw = per_solve(100, task, args.reps, "unscaled")
        counts = f"{base / 1e6:>10.2f} {fine / 1e6:>10.2f} {fine / base:>6.2f} {raw / 1e6:>10.2f}"
        print(f"{task:<8} {counts} {raw / base:>6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
