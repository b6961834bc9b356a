"""Statistics of the objective measures (paper §4.2), with statsmodels.

Measures: effort [N·m], interaction time [s], and the task cost *relative to the desired behaviour*,
``cost_error = |cost − desired_cost|`` (the paper's footnote 2: the absolute difference of the task
feature's value from that of the optimal trajectory).

- :func:`descriptives`: mean and SD (ddof = 1) per task and strategy.
- :func:`factorial_anova`: the paper's analysis — a two-way ANOVA with strategy and attempt as
  between factors over the pooled trials of the experimental tasks (familiarization left out):
  with 10 participants × 3 tasks × 2 strategies × 2 attempts = 120 observations it has the paper's
  F(1, 116) form. It ignores that trials of one participant are correlated.
- :func:`rm_anova`: the repeated-measures version (statsmodels ``AnovaRM``) with participant as the
  subject and strategy × attempt within; each participant's trials are averaged over the tasks first,
  so it has F(1, P − 1) form. Only the tasks a participant has in every strategy × attempt cell are
  averaged (:func:`matched_tasks`): a task missing for one strategy would otherwise pass for a
  strategy effect.
- :func:`task_tests`: that repeated-measures ANOVA per task (the asterisks of Fig. 4 and 5).

Effect sizes are partial η² = SS_effect / (SS_effect + SS_error); for the repeated-measures ANOVA,
whose table gives F and the degrees of freedom only, the identical F·df₁ / (F·df₁ + df₂).

A test is *not estimable* (column ``estimable`` False; F, p and partial η² NaN, never a number) when
its error term has no variance: zero up to floating-point rounding (:data:`ROUNDING`), as when every
participant's value is the same in each cell. Its F is then 0/0 or x/0 evaluated in floating point:
NaN, infinite, negative or absurdly large (F(1, 1) = −2·10³¹ or 7.9·10¹⁷), never a statistic.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from phri._extras import require

if TYPE_CHECKING:
    import pandas as pd
else:
    pd = require("pandas", __name__)

__all__ = [
    "MEASURES",
    "ROUNDING",
    "descriptives",
    "factorial_anova",
    "matched_tasks",
    "prepare",
    "rm_anova",
    "task_tests",
]

#: Analysed columns and their labels.
MEASURES: dict[str, str] = {
    "effort": "effort [N·m]",
    "interaction_time": "interaction time [s]",
    "cost_error": "|cost − desired cost|",
}
ANOVA_COLUMNS = ["measure", "effect", "df1", "df2", "F", "p", "partial_eta_sq", "estimable"]
#: An error sum of squares over n observations is taken for zero (rounding residue, not variance)
#: when its root mean square, √(SS/n), is at most this fraction of the data's largest magnitude.
ROUNDING = 1e-9


def prepare(table: pd.DataFrame) -> pd.DataFrame:
    """The episodes that completed (status "ok"), with ``cost_error = |cost − desired_cost|``."""
    ok = table[table["status"] == "ok"].copy()
    ok["cost_error"] = (ok["cost"] - ok["desired_cost"]).abs()
    for column in ("strategy", "task"):
        ok[column] = ok[column].astype(object)
    return ok


def descriptives(
    data: pd.DataFrame, measures: Sequence[str] = (*MEASURES, "cost", "desired_cost")
) -> pd.DataFrame:
    """Mean, SD (ddof = 1) and count per task and strategy, tasks in their study order."""
    tasks = list(dict.fromkeys(data["task"]))
    grouped = data.groupby(["task", "strategy"], sort=False)[list(measures)]
    out = grouped.agg(["mean", "std"])
    out.columns = [f"{m}_{s if s == 'mean' else 'sd'}" for m, s in out.columns]
    out.insert(0, "n", grouped.size())
    out = out.reset_index()
    out["task"] = pd.Categorical(out["task"], categories=tasks, ordered=True)
    return out.sort_values(["task", "strategy"]).reset_index(drop=True).astype({"task": object})


def _partial_eta_sq(f: float, df1: float, df2: float) -> float:
    return float(f * df1 / (f * df1 + df2)) if np.isfinite(f) else float("nan")


def _row(
    measure: str, effect: str, df1: float, df2: float, f: float, p: float, eta: float, error_zero: bool
) -> list[object]:
    """A row of an ANOVA table; a test that is not estimable (its error term without variance, or F,
    p or the degrees of freedom unusable) gets NaN for F, p and partial η²."""
    estimable = not error_zero and df1 > 0 and df2 > 0 and np.isfinite(f) and f >= 0 and 0 <= p <= 1
    if not estimable:
        f = p = eta = float("nan")
    return [measure, effect, df1, df2, f, p, eta, bool(estimable)]


def _zero_ss(ss: float, n: int, values: np.ndarray) -> bool:
    """Whether the sum of squares `ss` over `n` observations of `values` is zero up to rounding
    (NaN counts as zero)."""
    finite = values[np.isfinite(values)]
    scale = float(np.abs(finite).max()) if finite.size else 0.0
    return not ss > n * (ROUNDING * scale) ** 2


def _interaction_ss(cells: pd.DataFrame, value: str, factors: Sequence[str]) -> float:
    """The sum of squares of the interaction of `factors` (the main effect for one) over the rows of
    the balanced table `cells`: Σ over rows of (Σ over subsets U of the factors of
    (−1)^(|factors| − |U|) · mean of `value` over the rows sharing the row's levels of U)²."""
    y = cells[value].to_numpy(float)
    term = np.zeros_like(y)
    for k in range(len(factors) + 1):
        for subset in itertools.combinations(factors, k):
            means = (
                cells.groupby(list(subset))[value].transform("mean").to_numpy(float) if subset else y.mean()
            )
            term += (-1) ** (len(factors) - k) * means
    return float((term**2).sum())


def _factors(data: pd.DataFrame, factors: Sequence[str]) -> list[str]:
    """The factors that have at least two levels in `data`."""
    return [f for f in factors if data[f].nunique() > 1]


def factorial_anova(
    data: pd.DataFrame, measure: str, factors: Sequence[str] = ("strategy", "attempt")
) -> pd.DataFrame:
    """Between-factors ANOVA (statsmodels OLS, type II sums of squares) of `measure` over the rows of
    `data` — pass the pooled trials of the experimental tasks for the paper's F(1, 116) analysis."""
    smf = require("statsmodels.formula.api", __name__)
    anova_lm = require("statsmodels.stats.anova", __name__).anova_lm

    used = _factors(data, factors)
    if not used or len(data) <= 2 ** len(used):
        return pd.DataFrame(columns=ANOVA_COLUMNS)
    formula = f"{measure} ~ " + " * ".join(f"C({f})" for f in used)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # zero residual variance: F is inf or NaN
        model = smf.ols(formula, data=data.astype({f: str for f in used})).fit()
        table = anova_lm(model, typ=2)
    ss_error, df_error = float(table.loc["Residual", "sum_sq"]), float(table.loc["Residual", "df"])
    error_zero = _zero_ss(ss_error, len(data), data[measure].to_numpy(float))
    rows = []
    for effect, r in table.drop(index="Residual").iterrows():
        ss = float(r["sum_sq"])
        eta = ss / (ss + ss_error) if ss + ss_error > 0 else float("nan")
        name = str(effect).replace("C(", "").replace(")", "")
        f, p = float(r["F"]), float(r["PR(>F)"])
        rows.append(_row(measure, name, float(r["df"]), df_error, f, p, eta, error_zero))
    return pd.DataFrame(rows, columns=ANOVA_COLUMNS)


def matched_tasks(
    data: pd.DataFrame,
    within: Sequence[str] = ("strategy", "attempt"),
    subject: str = "participant",
    over: str = "task",
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The rows of `data` whose `over` level (task) the subject has in every cell of the factors
    `within` (those with two levels or more), and the (subject, task) pairs left out.

    Averaging a subject's cells over tasks compares like with like only if every cell holds the same
    tasks; a task missing from one cell (a failed or not yet run episode) is left out of all of that
    subject's cells. A subject with no such task is left out entirely."""
    used = _factors(data, within)
    if over not in data.columns or not used or not len(data):
        return data, pd.DataFrame(columns=[subject, over])
    n_cells = int(np.prod([data[f].nunique() for f in used]))
    per_pair = data.drop_duplicates([subject, over, *used]).groupby([subject, over], sort=False).size()
    full = per_pair[per_pair == n_cells].index
    keep = pd.MultiIndex.from_frame(data[[subject, over]]).isin(full)
    dropped = per_pair[per_pair != n_cells].index.to_frame(index=False)
    return data[keep], dropped.sort_values([subject]).reset_index(drop=True)


def rm_anova(
    data: pd.DataFrame,
    measure: str,
    within: Sequence[str] = ("strategy", "attempt"),
    subject: str = "participant",
    over: str = "task",
) -> pd.DataFrame:
    """Repeated-measures ANOVA (statsmodels AnovaRM) of `measure`, `subject` as the subject and the
    factors `within` (those with a single level are dropped). Each subject's observations per cell are
    averaged first over the levels of `over` (tasks) that the subject has in every cell (see
    :func:`matched_tasks`). Subjects missing a cell (failed episodes) are left out."""
    AnovaRM = require("statsmodels.stats.anova", __name__).AnovaRM

    data = data[data[measure].notna()]
    used = _factors(data, within)
    if not used:
        return pd.DataFrame(columns=ANOVA_COLUMNS)
    data, _ = matched_tasks(data, used, subject, over)
    cells = data.groupby([subject, *used], sort=True)[measure].mean().reset_index()
    n_cells = int(np.prod([cells[f].nunique() for f in used]))
    complete = cells.groupby(subject)[measure].count() == n_cells
    cells = cells[cells[subject].isin(complete[complete].index)]
    if cells[subject].nunique() < 2:
        return pd.DataFrame(columns=ANOVA_COLUMNS)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        table = AnovaRM(cells, measure, subject, within=list(used)).fit().anova_table
    values = cells[measure].to_numpy(float)
    rows = []
    for effect, r in table.iterrows():
        f, df1, df2 = float(r["F Value"]), float(r["Num DF"]), float(r["Den DF"])
        # The effect's error term is its interaction with the subject.
        error_ss = _interaction_ss(cells, measure, [*str(effect).split(":"), subject])
        eta = _partial_eta_sq(f, df1, df2)
        rows.append(_row(measure, str(effect), df1, df2, f, float(r["Pr > F"]), eta,
                         _zero_ss(error_ss, len(cells), values)))  # fmt: skip
    return pd.DataFrame(rows, columns=ANOVA_COLUMNS)


def task_tests(data: pd.DataFrame, measures: Sequence[str] = tuple(MEASURES)) -> pd.DataFrame:
    """Per task and measure, the repeated-measures ANOVA (strategy × attempt within participants);
    a row per effect with a `task` column."""
    frames = []
    for task in dict.fromkeys(data["task"]):
        for measure in measures:
            t = rm_anova(data[data["task"] == task], measure)
            if len(t):
                frames.append(t.assign(task=task))
    if not frames:
        return pd.DataFrame(columns=["task", *ANOVA_COLUMNS])
    out = pd.concat(frames, ignore_index=True)
    return out[["task", *ANOVA_COLUMNS]]
