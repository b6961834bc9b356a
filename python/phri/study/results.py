"""The study folder: its manifest, its tidy results table, and the episode logs.

Layout of a study folder::

    study.json          the manifest: the study's parameters (StudyConfig), seed, task digests
    participants.csv    each simulated participant's parameters and strategy order
    results.csv         the table, one row per finished episode, appended and fsync'ed as each ends
    results.parquet     the same table in session order, rewritten atomically as it goes (phri[parquet])
    logs/*.npz          each episode's compressed log (run_episode's arrays)

``results.csv`` is the journal: an episode is done exactly when its row is there. Rerunning the same
study on the folder skips those and runs the rest; a different study, or resuming with another phri
version than the one that started it, is refused (:class:`StudyMismatchError`) before anything is
touched. Floats are written with ``repr`` and read back exactly, so a resumed table is bit-for-bit the
table of an uninterrupted run.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import math
import os
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phri._extras import available, require
from phri.atomic import partial_path, write_atomic
from phri.study.errors import StudyFileError, StudyLockedError, StudyMismatchError
from phri.study.protocol import (
    TASKS_FOLDER,
    EpisodeSpec,
    StudyConfig,
    participant_params,
    schedule,
    strategy_order,
)

if TYPE_CHECKING:
    import pandas as pd

    from phri.config import Task
    from phri.sim.episode import EpisodeResult

__all__ = ["COLUMNS", "ResultStore", "episode_row", "failed_row", "load_results", "read_manifest"]

MANIFEST = "study.json"
RESULTS_CSV = "results.csv"
RESULTS_PARQUET = "results.parquet"
PARTICIPANTS_CSV = "participants.csv"
LOGS = "logs"
FORMAT = "phri-study"
FORMAT_VERSION = 2

#: The columns of the results table, in order, with their types.
COLUMNS: dict[str, type] = {
    "participant": int,  # 1-based
    "strategy": str,  # "impedance" or "learning"
    "order": int,  # 1-based position of the strategy in the participant's sequence
    "task": str,
    "attempt": int,  # 1-based
    "seed": int,  # the episode's seed (derived from the study seed)
    "status": str,  # "ok" or "failed" (a SimulationError; metrics NaN)
    "effort": float,  # Σ over interaction samples of Σ_j |u_H,j| [N·m]
    "interaction_time": float,  # interaction samples × sample period [s]
    "cost": float,  # task-feature count of the executed path
    "desired_cost": float,  # the same count for the desired (true-weight) plan
    "final_weight": float,  # final weight of the task's feature
    "final_weights": str,  # JSON {feature: final weight}
    "tracking_error": float,  # [m]
    "min_clearance": float,  # smallest distance of the arm or the cup to a scene object [m]
    "wall_contact_time": float,  # time the run-time virtual wall acted [s]
    "wall_peak_force": float,  # its largest total force [N]
    "wall_time": float,  # [s] (differs between runs; everything else does not)
    "log": str,  # path of the episode's .npz, relative to the study folder
    "error": str,  # the SimulationError's message for a failed episode
}
KEY = ("participant", "strategy", "task", "attempt")


def episode_row(spec: EpisodeSpec, result: EpisodeResult, task: Task, log: str) -> dict[str, Any]:
    """The table row of a finished episode."""
    weights = dict(zip(task.feature_names, (float(w) for w in result.final_weights), strict=True))
    return {
        "participant": spec.participant,
        "strategy": spec.strategy,
        "order": spec.order,
        "task": spec.task,
        "attempt": spec.attempt,
        "seed": spec.seed,
        "status": "ok",
        "effort": float(result.effort),
        "interaction_time": float(result.interaction_time),
        "cost": float(result.cost),
        "desired_cost": float(result.desired_cost),
        "final_weight": weights[task.task_feature],
        "final_weights": json.dumps(weights),
        "tracking_error": float(result.tracking_error),
        "min_clearance": float(result.min_clearance),
        "wall_contact_time": float(result.wall_contact_time),
        "wall_peak_force": float(result.wall_peak_force),
        "wall_time": float(result.wall_time),
        "log": log,
        "error": "",
    }


def failed_row(spec: EpisodeSpec, message: str, log: str) -> dict[str, Any]:
    """The row of an episode whose simulation failed: NaN metrics and the message."""
    nan = math.nan
    return {
        "participant": spec.participant, "strategy": spec.strategy, "order": spec.order, "task": spec.task,
        "attempt": spec.attempt, "seed": spec.seed, "status": "failed",
        "effort": nan, "interaction_time": nan, "cost": nan, "desired_cost": nan, "final_weight": nan,
        "final_weights": "{}", "tracking_error": nan, "min_clearance": nan, "wall_contact_time": nan,
        "wall_peak_force": nan, "wall_time": nan, "log": log,
        "error": " ".join(message.split()),
    }  # fmt: skip


def _format_row(row: dict[str, Any]) -> str:
    buffer = io.StringIO()
    # csv writes floats with repr(): shortest round-trip text, so reading gives back the same bits.
    csv.writer(buffer, lineterminator="\n").writerow([row[c] for c in COLUMNS])
    return buffer.getvalue()


def _parse_rows(path: Path, text: str) -> list[dict[str, Any]]:
    """The complete rows of results.csv; a torn last line (no newline: the writer was killed) is
    ignored. Anything else malformed is a StudyFileError naming the line."""
    if not text:
        raise StudyFileError(f"{path}: empty file (expected the header {','.join(COLUMNS)})")
    complete = text[: text.rfind("\n") + 1] if not text.endswith("\n") else text
    lines = list(csv.reader(io.StringIO(complete)))
    if not lines or lines[0] != list(COLUMNS):
        got = lines[0] if lines else []
        raise StudyFileError(f"{path}: line 1: expected the header {','.join(COLUMNS)}, got {','.join(got)}")
    rows = []
    for n, fields in enumerate(lines[1:], start=2):
        if len(fields) != len(COLUMNS):
            raise StudyFileError(f"{path}: line {n}: expected {len(COLUMNS)} fields, got {len(fields)}")
        row: dict[str, Any] = {}
        for (column, kind), value in zip(COLUMNS.items(), fields, strict=True):
            try:
                row[column] = kind(value)
            except ValueError:
                raise StudyFileError(
                    f"{path}: line {n}: column '{column}' must be {kind.__name__}, got {value!r}"
                ) from None
        rows.append(row)
    return rows


def read_manifest(run_dir: str | Path) -> tuple[StudyConfig, dict[str, Any]] | None:
    """(config, manifest) of the study in `run_dir`, or None if it holds no study.json."""
    path = Path(run_dir) / MANIFEST
    if not path.exists():
        return None
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise StudyFileError(
            f"{path}: not a readable study manifest ({e}); the folder was left untouched"
        ) from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise StudyFileError(f"{path}: not a phri study manifest (key 'format' must be {FORMAT!r})")
    if manifest.get("version") != FORMAT_VERSION:
        raise StudyFileError(
            f"{path}: key 'version' must be {FORMAT_VERSION}, got {manifest.get('version')!r}"
        )
    try:
        config = StudyConfig.from_dict(manifest.get("config"), f"{path}: config")  # type: ignore[arg-type]
    except ValueError as e:
        raise StudyFileError(f"{e} (the folder was left untouched)") from None
    # Its tasks given as paths are the folder's own copies, whatever the working directory.
    return dataclasses.replace(config, folder=Path(run_dir).resolve()), manifest


def _differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    return [
        f"{k}: {a.get(k)!r} here, {b.get(k)!r} asked" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)
    ]


def _check_version(run_dir: Path, manifest: dict[str, Any], allowed: bool) -> None:
    """Refuses to resume a study that another phri version started (unless `allowed`)."""
    from phri import __version__

    started = manifest.get("phri_version")
    if started == __version__ or allowed:
        return
    was = f"phri {started}" if started else "an unknown phri version"
    raise StudyMismatchError(
        f"{run_dir}: this study was started with {was}, this is phri {__version__}; resuming would mix "
        "results of two versions in one table. Run the study into a new folder (or pass "
        "--allow-version-change / allow_version_change=True to resume anyway); nothing was changed"
    )


class ResultStore:
    """A study folder opened for writing (one writer at a time: an advisory lock on the folder).

    Use :meth:`open`; then :meth:`record` each finished episode and :meth:`export` the Parquet table."""

    def __init__(
        self, run_dir: Path, config: StudyConfig, specs: list[EpisodeSpec], rows: list[dict[str, Any]]
    ):
        self.run_dir, self.config, self.specs = run_dir, config, specs
        self._index = {s.key: s for s in specs}
        self.rows: dict[tuple[Any, ...], dict[str, Any]] = {tuple(r[k] for k in KEY): r for r in rows}
        self._lock_fd: int | None = None
        self.log_width = _log_width(config)

    # -- opening ---------------------------------------------------------------------------------

    @classmethod
    def open(
        cls, run_dir: str | Path, config: StudyConfig | None = None, *, allow_version_change: bool = False
    ) -> ResultStore:
        """Opens (or creates) the study folder `run_dir` for `config`.

        With `config` None the folder's own study is resumed (a folder without one gets the default
        study). Raises :class:`StudyMismatchError` if the folder holds a different study or was started
        with another phri version (unless `allow_version_change`: the simulator or the analysis may
        differ, and the rows do not say which version wrote them), and :class:`StudyFileError` if its
        files are broken or it holds results without a manifest."""
        run_dir = Path(run_dir)
        if run_dir.exists() and not run_dir.is_dir():
            raise StudyFileError(f"{run_dir}: exists and is not a folder")
        created = not run_dir.exists()
        run_dir.mkdir(parents=True, exist_ok=True)
        # The lock first, then the manifest: a second writer that read the folder before the first
        # one finished it would otherwise take it for new.
        lock_fd = _lock(run_dir)
        try:
            return cls._open_locked(run_dir, config, allow_version_change, lock_fd)
        except BaseException:
            _unlock(lock_fd)
            if created:
                with contextlib.suppress(OSError):
                    run_dir.rmdir()  # only if still empty: nothing was changed
            raise

    @classmethod
    def _open_locked(
        cls, run_dir: Path, config: StudyConfig | None, allow_version_change: bool, lock_fd: int | None
    ) -> ResultStore:
        """:meth:`open` once the folder's lock is held."""
        existing = read_manifest(run_dir)
        if existing is None:
            leftovers = [
                n for n in (RESULTS_CSV, RESULTS_PARQUET, LOGS, PARTICIPANTS_CSV) if (run_dir / n).exists()
            ]
            if leftovers:
                raise StudyFileError(
                    f"{run_dir}: holds {', '.join(leftovers)} but no {MANIFEST}: not a phri study folder or "
                    "a damaged one; choose an empty folder (nothing was changed)"
                )
            config = config or StudyConfig()
        else:
            found, manifest = existing
            # The study as given (its task paths read where they are) must be the folder's study.
            given = config.in_folder(run_dir) if config is not None else found
            if given != found:
                differences = "; ".join(_differences(found.to_dict(), given.to_dict()))
                raise StudyMismatchError(
                    f"{run_dir}: holds another study's results ({differences}). "
                    "Run it into a new folder, or resume this one without study options; nothing was changed"
                )
            # The folder's copies of the task files, and the files given now, as when it started.
            for asked in (found, config) if config is not None else (found,):
                digests = asked.task_digests()
                if manifest.get("task_digests") != digests:
                    changed = [t for t in digests if manifest.get("task_digests", {}).get(t) != digests[t]]
                    raise StudyMismatchError(
                        f"{run_dir}: the task file(s) {changed} changed since this study started; "
                        "its results would mix two task definitions (nothing was changed)"
                    )
            _check_version(run_dir, manifest, allow_version_change)
            config = found
        config.load_tasks()  # every task file readable before anything is written
        specs = schedule(config)
        copies = config.task_files() if existing is None else {}
        if existing is None:
            config = config.in_folder(run_dir)  # its task files are read from the folder's copies
        store = cls(run_dir, config, specs, [])
        if existing is None:
            store._create(copies)
        else:
            store._note_version(existing[1])
        store._load()
        store._lock_fd = lock_fd  # the store releases it from now on
        return store

    def _create(self, task_files: Mapping[str, Path]) -> None:
        """Writes a new study folder; `task_files` are copied into its tasks/ by their names there."""
        from phri import __version__

        if task_files:
            (self.run_dir / TASKS_FOLDER).mkdir(exist_ok=True)
            for name, source in task_files.items():
                (self.run_dir / TASKS_FOLDER / name).parent.mkdir(parents=True, exist_ok=True)
                write_atomic(self.run_dir / TASKS_FOLDER / name, source.read_bytes())
        manifest = {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "config": self.config.to_dict(),
            "task_digests": self.config.task_digests(),
            "episodes": len(self.specs),
            "phri_version": __version__,
            "python": sys.version.split()[0],
        }
        (self.run_dir / LOGS).mkdir(exist_ok=True)
        people = io.StringIO()
        writer = csv.writer(people, lineterminator="\n")
        params = [
            participant_params(self.config.seed, p, self.config.population)
            for p in range(1, self.config.participants + 1)
        ]
        fields = list(params[0].as_dict())
        writer.writerow(["participant", "strategy_order", *fields])
        for p, pp in enumerate(params, start=1):
            writer.writerow([p, " ".join(strategy_order(self.config, p)), *pp.as_dict().values()])
        write_atomic(self.run_dir / PARTICIPANTS_CSV, people.getvalue().encode())
        write_atomic(self.run_dir / RESULTS_CSV, _format_header().encode())
        # The manifest last: a folder with a manifest is a complete, resumable study folder.
        write_atomic(self.run_dir / MANIFEST, (json.dumps(manifest, indent=2) + "\n").encode())

    def _note_version(self, manifest: dict[str, Any]) -> None:
        """Adds this phri version to the manifest's `resumed_with` if it is not the one that started
        the study (resuming across versions was allowed): the folder keeps saying it is mixed."""
        from phri import __version__

        versions = list(manifest.get("resumed_with", []))
        if manifest.get("phri_version") == __version__ or __version__ in versions:
            return
        updated = {**manifest, "resumed_with": [*versions, __version__]}
        write_atomic(self.run_dir / MANIFEST, (json.dumps(updated, indent=2) + "\n").encode())

    def _load(self) -> None:
        path = self.run_dir / RESULTS_CSV
        if not path.exists():
            raise StudyFileError(
                f"{path}: missing although {MANIFEST} is there; the folder is damaged (nothing was changed)"
            )
        text, torn = _read_complete(path)
        self.rows = _study_rows(path, _parse_rows(path, text), self._index, self.log_width)
        if torn:
            # A row torn by a kill: it was never complete, so its episode is run again.
            with open(path, "r+b") as f:
                f.truncate(len(text.encode("utf-8")))
        # Logs of episodes that never got their row (killed in between) are redone identically.
        logs = self.run_dir / LOGS
        logs.mkdir(exist_ok=True)
        recorded = {Path(str(r["log"])).name for r in self.rows.values()}
        for spec in self.specs:
            name = spec.log_name(self.log_width)
            if name not in recorded:
                for stale in (logs / name, partial_path(logs / name)):
                    stale.unlink(missing_ok=True)

    # -- state -----------------------------------------------------------------------------------

    def pending(self) -> list[EpisodeSpec]:
        """Episodes without a row yet, in session order."""
        return [s for s in self.specs if s.key not in self.rows]

    @property
    def complete(self) -> bool:
        """Whether every scheduled episode has its row."""
        return len(self.rows) == len(self.specs)

    # -- writing ---------------------------------------------------------------------------------

    def record(self, spec: EpisodeSpec, row: dict[str, Any], log: bytes) -> None:
        """Writes the episode's log, then appends its row (fsync'ed): from then on it is done."""
        if spec.key in self.rows:
            raise StudyFileError(f"{self.run_dir}: episode {spec.key} is already recorded")
        if log:
            write_atomic(self.run_dir / LOGS / spec.log_name(self.log_width), log, overwrite=False)
        with open(self.run_dir / RESULTS_CSV, "a", encoding="utf-8", newline="") as f:
            f.write(_format_row(row))
            f.flush()
            os.fsync(f.fileno())
        self.rows[spec.key] = row

    def table(self) -> pd.DataFrame:
        """The rows so far, in session order."""
        return _frame(self.rows[s.key] for s in self.specs if s.key in self.rows)

    def export(self, *, sort_csv: bool = False) -> None:
        """Rewrites results.parquet (atomically) from the rows so far, if pyarrow (``phri[parquet]``)
        is installed; with `sort_csv`, also rewrites results.csv in session order (same rows, atomic
        replace)."""
        if available("pyarrow"):
            buffer = io.BytesIO()
            self.table().to_parquet(buffer, index=False)
            write_atomic(self.run_dir / RESULTS_PARQUET, buffer.getvalue())
        if sort_csv:
            text = _format_header() + "".join(
                _format_row(self.rows[s.key]) for s in self.specs if s.key in self.rows
            )
            if (self.run_dir / RESULTS_CSV).read_text(encoding="utf-8") != text:
                write_atomic(self.run_dir / RESULTS_CSV, text.encode("utf-8"))

    def close(self) -> None:
        """Releases the study folder's lock."""
        _unlock(self._lock_fd)
        self._lock_fd = None

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _log_width(config: StudyConfig) -> int:
    """Digits of the participant number in the study's log names."""
    return max(2, len(str(config.participants)))


def _study_rows(
    path: Path, rows: list[dict[str, Any]], index: Mapping[tuple[Any, ...], EpisodeSpec], log_width: int
) -> dict[tuple[Any, ...], dict[str, Any]]:
    """`rows` of results.csv `path` by episode key, each checked to be an episode of the study
    (`index`: its episodes by key), recorded once, and naming no log but its own in the folder's
    logs/ (or none; a report opens it); else a StudyFileError naming the line."""
    out: dict[tuple[Any, ...], dict[str, Any]] = {}
    for n, row in enumerate(rows, start=2):
        key = tuple(row[k] for k in KEY)
        spec = index.get(key)
        if spec is None or spec.seed != row["seed"] or spec.order != row["order"]:
            raise StudyFileError(
                f"{path}: line {n}: an episode {dict(zip(KEY, key, strict=True))} not in this study"
            )
        own = f"{LOGS}/{spec.log_name(log_width)}"
        if row["log"] not in ("", own):
            raise StudyFileError(
                f"{path}: line {n}: the log of episode {dict(zip(KEY, key, strict=True))} must be "
                f"{own!r} (or none), got {row['log']!r}"
            )
        if key in out:
            raise StudyFileError(
                f"{path}: line {n}: episode {dict(zip(KEY, key, strict=True))} is recorded twice"
            )
        out[key] = row
    return out


def _read_complete(path: Path) -> tuple[str, bool]:
    """The complete lines of results.csv `path` as text, and whether a torn last row (a kill during
    its write, which may end inside a multi-byte character) was left out."""
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1
    try:
        return data[:end].decode("utf-8"), end < len(data)
    except UnicodeDecodeError as e:
        raise StudyFileError(f"{path}: byte {e.start} is not UTF-8; the file is damaged") from None


def _lock(run_dir: Path) -> int | None:
    """An advisory lock on the folder `run_dir` itself (no lock file is left behind): its
    descriptor, or None where there are no advisory locks. Another holder is StudyLockedError."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows: no advisory lock
        return None
    fd = os.open(run_dir, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise StudyLockedError(f"{run_dir}: another process is running a study into this folder") from None
    return fd


def _unlock(fd: int | None) -> None:
    if fd is not None:
        os.close(fd)  # closing the descriptor releases the lock


def _format_header() -> str:
    return ",".join(COLUMNS) + "\n"


def _frame(rows: Iterable[dict[str, Any]]) -> pd.DataFrame:
    pd = require("pandas", __name__)

    table = pd.DataFrame(list(rows), columns=list(COLUMNS))
    for column, kind in COLUMNS.items():
        table[column] = table[column].astype({int: np.int64, float: np.float64, str: "string"}[kind])
    return table


def load_results(run_dir: str | Path) -> pd.DataFrame:
    """The results table of a study folder, in session order (read-only; works while it runs)."""
    run_dir = Path(run_dir)
    found = read_manifest(run_dir)
    if found is None:
        raise StudyFileError(f"{run_dir}: no {MANIFEST}; not a phri study folder")
    config, _ = found
    path = run_dir / RESULTS_CSV
    if not path.exists():
        raise StudyFileError(f"{path}: missing although {MANIFEST} is there")
    specs = schedule(config)
    # The rows `phri study` would accept, or its error: duplicated or foreign rows are never counted.
    rows = list(
        _study_rows(
            path, _parse_rows(path, _read_complete(path)[0]), {s.key: s for s in specs}, _log_width(config)
        ).values()
    )
    order = {s.key: s.index for s in specs}
    rows.sort(key=lambda r: order.get(tuple(r[k] for k in KEY), len(order)))  # type: ignore[arg-type]
    return _frame(rows)
