"""Reference statistics of a study, as a CSV file: what ``phri calibrate`` fits a population to and
what ``phri report --reference`` compares a study with.

The format (UTF-8, comma-separated, a header row, ``#`` comment lines allowed)::

    task,strategy,effort,interaction_time,effort_per_sample,effort_sd,interaction_time_sd,effort_per_sample_sd,f_effort,f_interaction_time,f_cost,df_error
    coffee,impedance,260.2,5.37,4.8,,,,,,,
    coffee,learning,94.8,2.34,4.1,,,,,,,
    coffee+table+laptop,,,,,,,,86.29,75.52,21.85,116

Columns ``task`` and ``strategy`` are required, the others optional (a missing column or an empty
cell: no target). Two kinds of row:

- a **cell** (task and strategy given): the mean over its trials of the effort [N·m] (Σ over
  interaction samples of the L1 norm of the thresholded joint torques), the interaction time [s] and
  the effort per interaction sample [N·m] (the mean effort over the mean number of samples, as the
  study's table reports it), each with an optional standard deviation across trials (``*_sd``);
- a **pooled test** (strategy empty, task the pooled tasks joined by ``+``): the F of the strategy
  effect in the paper's factorial ANOVA (strategy × attempt over the pooled trials) for effort,
  interaction time and cost (|cost − desired cost|), with its error degrees of freedom ``df_error``
  (116 in the paper: 120 trials).

Every number is finite and > 0 (an SD or F of 0 is no target: calibration fits the log of each
ratio). Bad input is a :class:`TargetsError` naming the file, the line and the column.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from phri._validate import decode_utf8, did_you_mean
from phri.exceptions import ConfigError
from phri.sim.episode import STRATEGIES

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "COLUMNS",
    "MEASURES",
    "Cell",
    "PooledTest",
    "Targets",
    "TargetsError",
    "compare",
    "reference_names",
    "read_targets",
    "simulated",
]

#: The cell measures, their units.
MEASURES: dict[str, str] = {
    "effort": "N·m",
    "interaction_time": "s",
    "effort_per_sample": "N·m",
}
#: The pooled tests' F columns and the results-table measure each is the F of.
F_COLUMNS: dict[str, str] = {
    "f_effort": "effort",
    "f_interaction_time": "interaction_time",
    "f_cost": "cost_error",
}
#: Every column a targets file may have, in any order (``task`` and ``strategy`` are required).
COLUMNS = ("task", "strategy", *MEASURES, *(f"{m}_sd" for m in MEASURES), *F_COLUMNS, "df_error")


class TargetsError(ConfigError):
    """A reference statistics (targets) file that cannot be used."""


@dataclass(frozen=True)
class Cell:
    """The reference means (and SDs) of one task under one strategy."""

    task: str
    strategy: str
    means: tuple[tuple[str, float], ...]
    sds: tuple[tuple[str, float], ...] = ()


@dataclass(frozen=True)
class PooledTest:
    """The strategy effect's F over the pooled trials of `tasks`, per measure, with F(1, df_error)."""

    tasks: tuple[str, ...]
    f: tuple[tuple[str, float], ...]
    df_error: float

    def partial_eta_sq(self, measure: str) -> float:
        """The effect size the F implies: F / (F + df_error) (F(1, ·))."""
        f = dict(self.f)[measure]
        return f / (f + self.df_error)


@dataclass(frozen=True)
class Targets:
    """A reference statistics file's contents."""

    cells: tuple[Cell, ...]
    pooled: tuple[PooledTest, ...] = ()
    source: str = "<memory>"

    @property
    def tasks(self) -> list[str]:
        """The tasks with cell targets, in file order."""
        return list(dict.fromkeys(c.task for c in self.cells))

    @property
    def strategies(self) -> list[str]:
        """The strategies with cell targets, in file order."""
        return list(dict.fromkeys(c.strategy for c in self.cells))

    def check_tasks(self, available: Sequence[str], what: str, pooled: bool = True) -> None:
        """Every task the targets name (the pooled tests' too, if `pooled`) must be among `available`
        (e.g. the study's tasks)."""
        missing = [t for t in self.tasks if t not in available]
        for test in self.pooled if pooled else ():
            missing += [t for t in test.tasks if t not in available and t not in missing]
        if missing:
            raise TargetsError(f"{self.source}: task(s) {missing} are not among {what} {list(available)}")


def _number(source: str, line: int, column: str, text: str) -> float:
    """A target: finite and > 0 (calibration fits log-ratios, and a report divides by it)."""
    try:
        v = float(text)
    except ValueError:
        raise TargetsError(f"{source}: line {line}, column '{column}': not a number: {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise TargetsError(
            f"{source}: line {line}, column '{column}' must be a finite number > 0, got {text}"
        )
    return v


def _parse(text: str, source: str) -> Targets:
    lines = [(i, line) for i, line in enumerate(text.split("\n"), start=1) if line.strip()]
    lines = [(i, line) for i, line in lines if not line.lstrip().startswith("#")]
    if not lines:
        raise TargetsError(f"{source}: empty; expected a header row ({', '.join(COLUMNS[:2])}, ...)")
    rows = list(csv.reader(io.StringIO("\n".join(line for _, line in lines))))
    header = [h.strip() for h in rows[0]]
    for h in header:
        if h not in COLUMNS:
            raise TargetsError(
                f"{source}: line {lines[0][0]}: unknown column '{h}'; known: {', '.join(COLUMNS)}"
                f"{did_you_mean(h, COLUMNS)}"
            )
    for required in ("task", "strategy"):
        if required not in header:
            raise TargetsError(f"{source}: line {lines[0][0]}: missing column '{required}'")
    if len(set(header)) != len(header):
        raise TargetsError(f"{source}: line {lines[0][0]}: a column appears twice: {header}")
    cells: list[Cell] = []
    pooled: list[PooledTest] = []
    seen: set[tuple[str, str]] = set()
    for (line, _), row in zip(lines[1:], rows[1:], strict=True):
        if len(row) != len(header):
            raise TargetsError(f"{source}: line {line}: {len(row)} fields, the header has {len(header)}")
        r = {h: v.strip() for h, v in zip(header, row, strict=True)}
        task, strategy = r["task"], r["strategy"]
        if not task:
            raise TargetsError(f"{source}: line {line}, column 'task': empty")
        if strategy:
            if strategy not in STRATEGIES:
                raise TargetsError(
                    f"{source}: line {line}, column 'strategy' must be one of {STRATEGIES} (or empty for a "
                    f"pooled test), got {strategy!r}"
                )
            if (task, strategy) in seen:
                raise TargetsError(f"{source}: line {line}: a second row for task {task!r}, {strategy}")
            seen.add((task, strategy))
            stray = [c for c in (*F_COLUMNS, "df_error") if r.get(c)]
            if stray:
                raise TargetsError(
                    f"{source}: line {line}: column '{stray[0]}' belongs to a pooled test (a row with an "
                    "empty strategy), not to a task × strategy cell"
                )
            means = tuple((m, _number(source, line, m, r[m])) for m in MEASURES if r.get(m))
            sds = tuple(
                (m, _number(source, line, f"{m}_sd", r[f"{m}_sd"])) for m in MEASURES if r.get(f"{m}_sd")
            )
            if not means:
                raise TargetsError(
                    f"{source}: line {line}: no target for {task}/{strategy}; give at least one of "
                    f"{', '.join(MEASURES)}"
                )
            for m, _ in sds:
                if m not in dict(means):
                    raise TargetsError(
                        f"{source}: line {line}, column '{m}_sd': an SD without the mean '{m}'"
                    )
            cells.append(Cell(task, strategy, means, sds))
        else:
            stray = [c for c in (*MEASURES, *(f"{m}_sd" for m in MEASURES)) if r.get(c)]
            if stray:
                raise TargetsError(
                    f"{source}: line {line}, column '{stray[0]}': a row without a strategy is a pooled "
                    "test, which takes F values (f_effort, f_interaction_time, f_cost, df_error) only"
                )
            fs = tuple(
                (measure, _number(source, line, column, r[column]))
                for column, measure in F_COLUMNS.items()
                if r.get(column)
            )
            if not fs:
                raise TargetsError(f"{source}: line {line}: a pooled test without any F value")
            if not r.get("df_error"):
                raise TargetsError(f"{source}: line {line}, column 'df_error': missing (116 in the paper)")
            df = _number(source, line, "df_error", r["df_error"])
            tasks = tuple(t.strip() for t in task.split("+") if t.strip())
            pooled.append(PooledTest(tasks, fs, df))
    if not cells:
        raise TargetsError(f"{source}: no task × strategy rows (a row per task and strategy)")
    return Targets(tuple(cells), tuple(pooled), source)


def reference_names() -> list[str]:
    """Names of the reference statistics shipped with phri (``corl2017``: the paper's study)."""
    folder = resources.files("phri").joinpath("populations")
    return sorted(p.name[:-4] for p in folder.iterdir() if p.name.endswith(".csv"))


def read_targets(name_or_path: str | Path) -> Targets:
    """A shipped reference by name (``"corl2017"``) or a targets CSV file."""
    spec = str(name_or_path)
    if not isinstance(name_or_path, Path) and spec in reference_names():
        source = f"phri/populations/{spec}.csv"
        raw = resources.files("phri").joinpath("populations", f"{spec}.csv").read_bytes()
    else:
        path = Path(name_or_path)
        source = str(path)
        if not path.is_file():
            known = ", ".join(reference_names())
            raise TargetsError(
                f"{source}: targets file not found (or not a regular file); shipped references: {known}"
            )
        raw = path.read_bytes()
    text = decode_utf8(
        raw,
        lambda line, offset, bad: TargetsError(
            f"{source}: not UTF-8 text (line {line}, byte {offset}: {bad!r})"
        ),
    )
    return _parse(text, source)


def simulated(data: pd.DataFrame, sample_rate: float) -> dict[tuple[str, str], dict[str, float]]:
    """Each (task, strategy)'s simulated means and SDs of the measures from completed episodes (the
    study's results table, status "ok"): keys like ``effort`` and ``effort_sd``. Effort per sample is
    the mean effort over the mean number of interaction samples (its SD: per trial with samples)."""
    out: dict[tuple[str, str], dict[str, float]] = {}
    for (task, strategy), g in data.groupby(["task", "strategy"], sort=False):
        samples = g["interaction_time"] * sample_rate
        per = g["effort"][samples > 0] / samples[samples > 0]
        mean_samples = float(samples.mean())
        out[(str(task), str(strategy))] = {
            "effort": float(g["effort"].mean()),
            "effort_sd": float(g["effort"].std()),
            "interaction_time": float(g["interaction_time"].mean()),
            "interaction_time_sd": float(g["interaction_time"].std()),
            "effort_per_sample": float(g["effort"].mean()) / mean_samples if mean_samples > 0 else 0.0,
            "effort_per_sample_sd": float(per.std()) if len(per) > 1 else math.nan,
            "n": float(len(g)),
        }
    return out


def pooled_f(data: pd.DataFrame, tasks: Sequence[str]) -> dict[str, tuple[float, float]]:
    """The strategy effect's (F, df_error) per measure in the factorial ANOVA over `tasks`' trials."""
    from phri.study import analysis

    rows = data[data["task"].isin(list(tasks))]
    out = {}
    for measure in F_COLUMNS.values():
        table = analysis.factorial_anova(rows, measure)
        hit = table[table["effect"] == "strategy"] if len(table) else table
        out[measure] = (
            (float(hit["F"].iloc[0]), float(hit["df2"].iloc[0])) if len(hit) else (math.nan, math.nan)
        )
    return out


def compare(targets: Targets, data: pd.DataFrame, sample_rate: float) -> list[dict[str, Any]]:
    """Per target, the reference, the simulated value and their ratio (simulated / reference):
    rows with task, strategy, statistic, reference, simulated, ratio (a pooled test's also df and
    df_reference: its F's error degrees of freedom). `data` holds completed episodes with
    ``cost_error`` (phri.study.analysis.prepare)."""
    sim = simulated(data, sample_rate)
    rows: list[dict[str, Any]] = []
    for cell in targets.cells:
        got: Mapping[str, float] = sim.get((cell.task, cell.strategy), {})
        for key, ref in (*cell.means, *((f"{m}_sd", v) for m, v in cell.sds)):
            value = got.get(key, math.nan)
            rows.append({"task": cell.task, "strategy": cell.strategy, "statistic": key, "reference": ref,
                         "simulated": value, "ratio": value / ref if ref else math.nan})  # fmt: skip
    for test in targets.pooled:
        fs = pooled_f(data, test.tasks)
        for measure, ref in test.f:
            value, df = fs[measure]
            rows.append({"task": "+".join(test.tasks), "strategy": "", "statistic": f"F strategy ({measure})",
                         "reference": ref, "simulated": value, "ratio": value / ref if ref else math.nan,
                         "df_reference": test.df_error, "df": df})  # fmt: skip
    return rows
