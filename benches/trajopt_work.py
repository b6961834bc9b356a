"""Instructions per repeated cold trajectory solve, N = 100 against N = 31, counted under callgrind.

Times on a shared machine move by ±40% between (and within) runs; instruction counts do not (nor do
they count cache misses, which grow with N: a check on the time ratios, not a replacement). For each
study task this runs `trajopt_work` (benches/trajopt_work.rs) under `valgrind --tool=callgrind` with
1 and 1 + REPS solves and takes the difference, so the count excludes start-up (URDF parsing) and the
first solve's allocations, for N = 31 and for N = 100 posed with the trade-off of 31 waypoints
(weights and clearance rescaled) and with the study's weights unscaled.

    python3 benches/trajopt_work.py [--reps 5]     (or `make bench-trajopt-work`; needs valgrind)
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("human", "coffee", "table", "laptop")


def build() -> Path:
    """Builds trajopt_work and returns its path (in cargo's target directory, wherever that is)."""
    subprocess.run(
        ["cargo", "build", "--release", "-q", "-p", "phri_benches", "--bin", "trajopt_work"],
        cwd=ROOT,
        check=True,
    )
    meta = subprocess.run(
        ["cargo", "metadata", "--format-version", "1", "--no-deps"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    return Path(json.loads(meta.stdout)["target_directory"]) / "release" / "trajopt_work"


def instructions(binary: Path, *args: str) -> int:
    cmd = ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", str(binary), *args]
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"trajopt_work {' '.join(args)} failed:\n{out.stderr}")
    match = re.search(r"Collected : (\d+)", out.stderr)
    if match is None:
        raise RuntimeError(f"no instruction count from callgrind:\n{out.stderr}")
    return int(match.group(1))


def per_solve(binary: Path, n: int, task: str, reps: int, *extra: str) -> float:
    one = instructions(binary, str(n), task, "1", *extra)
    return (instructions(binary, str(n), task, str(1 + reps), *extra) - one) / reps


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=5, help="solves counted per case")
    args = ap.parse_args()
    if args.reps < 1:
        ap.error(f"--reps must be >= 1, got {args.reps}")
    if shutil.which("valgrind") is None:
        print("valgrind is not installed (apt-get install valgrind)", file=sys.stderr)
        return 1
    binary = build()
    print("10⁶ instructions per cold solve; N = 100 posed as on 31 waypoints (rescaled), then unscaled")
    print(f"{'task':<8} {'N=31':>10} {'N=100':>10} {'ratio':>6} {'unscaled':>10} {'ratio':>6}")
    for task in TASKS:
        base = per_solve(binary, 31, task, args.reps)
        fine = per_solve(binary, 100, task, args.reps)
        raw = per_solve(binary, 100, task, args.reps, "unscaled")
        counts = f"{base / 1e6:>10.2f} {fine / 1e6:>10.2f} {fine / base:>6.2f} {raw / 1e6:>10.2f}"
        print(f"{task:<8} {counts} {raw / base:>6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
