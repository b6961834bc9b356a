"""``phri report RUN_DIR``: the statistics, the figures and a Markdown report of a study folder.

Writes a new folder ``RUN_DIR/report/`` (or `out`): ``report.md``, the PNG figures, and the tables
behind them as CSV. If that folder exists (an earlier report, perhaps edited by hand) it is left as
it is and the report goes to ``report-2``, ``report-3``, ...: written once, a report is never
overwritten. The report is written into a hidden sibling folder renamed into place when complete,
so a failing report leaves nothing behind. The study's own files are only read.
"""

from __future__ import annotations

import errno
import os
import secrets
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from phri.study import analysis, figures, markdown
from phri.study.errors import StudyConfigError, StudyFileError
from phri.study.markdown import number, p_value
from phri.study.protocol import StudyConfig
from phri.study.results import load_results, read_manifest

__all__ = ["QUESTIONNAIRE_CSV", "write_report"]

#: Where a study folder keeps its questionnaire answers (see phri.study.questionnaire).
QUESTIONNAIRE_CSV = "questionnaire.csv"


def _md(table: pd.DataFrame, formats: dict[str, Callable[[object], str]] | None = None) -> str:
    """`table` as Markdown; `formats` by column (default: strings as they are, numbers as
    :func:`markdown.number`)."""
    formats = formats or {}

    def cell(column: str, value: object) -> str:
        if column in formats:
            return formats[column](value)
        return value if isinstance(value, str) else number(value)

    rows = ([cell(c, row[c]) for c in table.columns] for _, row in table.iterrows())
    return markdown.table([str(c) for c in table.columns], rows)


def _anova_md(table: pd.DataFrame) -> str:
    if not len(table):
        return "_Not enough data (needs at least two levels of a factor, and two complete participants)._\n"
    t = table.copy()
    t.insert(0, "F(df1, df2)", [f"F({r.df1:g}, {r.df2:g}) = {number(r.F, 2)}" for r in t.itertuples()])
    t["measure"] = t["measure"].map(lambda m: analysis.MEASURES.get(m, m))
    cols = [c for c in ("task", "measure", "effect", "F(df1, df2)", "p", "partial_eta_sq") if c in t]
    return _md(t[cols].rename(columns={"partial_eta_sq": "partial η²"}), {"p": p_value, "F(df1, df2)": str})


def _descriptives_md(desc: pd.DataFrame) -> str:
    rows = []
    for r in desc.itertuples():
        rows.append({
            "task": r.task, "strategy": r.strategy, "n": str(r.n),
            "effort [N·m]": f"{number(r.effort_mean, 1)} ± {number(r.effort_sd, 1)}",
            "interaction time [s]":
                f"{number(r.interaction_time_mean, 2)} ± {number(r.interaction_time_sd, 2)}",
            "cost": f"{number(r.cost_mean)} ± {number(r.cost_sd)}",
            "desired cost": number(r.desired_cost_mean),
            "abs(cost − desired)": f"{number(r.cost_error_mean)} ± {number(r.cost_error_sd)}",
        })  # fmt: skip
    return _md(pd.DataFrame(rows), {c: str for c in rows[0]}) if rows else "_No completed episodes._\n"


def _sample_logs(
    run_dir: Path, table: pd.DataFrame, participant: int | None, task: str | None, strategies: Sequence[str]
) -> tuple[int, str, dict[str, Path]] | None:
    """Participant, task and {strategy: log} of the sample shown in Fig. 5 (right): the requested
    ones, else the laptop task (else the last task) of the first participant with a log for each strategy."""
    tasks = list(dict.fromkeys(table["task"]))
    if not tasks:
        return None
    task = task or ("laptop" if "laptop" in tasks else tasks[-1])
    people = [participant] if participant is not None else list(dict.fromkeys(table["participant"]))
    for p in people:
        logs: dict[str, Path] = {}
        for s in strategies:
            hit = table[(table["participant"] == p) & (table["task"] == task) & (table["strategy"] == s)]
            hit = hit[hit["log"].str.len() > 0].sort_values("attempt")
            if len(hit) and (run_dir / hit["log"].iloc[0]).exists():
                logs[s] = run_dir / hit["log"].iloc[0]
        if len(logs) == len(strategies):
            return int(p), task, logs
    return None


def _check_sample(config: StudyConfig, participant: int | None, task: str | None) -> None:
    """The requested sample of the path figure must be in the study (not silently no figure)."""
    if participant is not None and not 1 <= participant <= config.participants:
        raise StudyConfigError(
            f"report: participant (--participant) must be one of the study's participants "
            f"1-{config.participants}, got {participant}"
        )
    if task is not None and task not in (names := config.task_names()):
        raise StudyConfigError(
            f"report: task (--task) must be one of the study's tasks {names}, got {task!r}"
        )


def _pooled_form(pooled: pd.DataFrame) -> str:
    """The F form the pooled ANOVA actually has; the paper's only when it is F(1, 116)."""
    forms = sorted({(float(r.df1), float(r.df2)) for r in pooled.itertuples()})
    if not forms:
        return "No F test could be computed from these trials yet."
    text = " and ".join(f"F({a:g}, {b:g})" for a, b in forms)
    if forms == [(1.0, 116.0)]:
        return (
            "Here it has the paper's F(1, 116) form (10 participants × 3 tasks × 2 strategies × 2 attempts)."
        )
    return (
        f"Here it has the form {text}; the paper's F(1, 116) is that of 10 participants × 3 tasks × "
        "2 strategies × 2 attempts = 120 trials."
    )


def _matching_note(dropped: pd.DataFrame, data: pd.DataFrame) -> str:
    """Which participants' tasks the repeated-measures ANOVA left out, and why."""
    if not len(dropped):
        return ""
    parts = []
    for p, group in dropped.groupby("participant", sort=True):
        left = sorted(set(data.loc[data["participant"] == p, "task"]) - set(group["task"]))
        names = ", ".join(f"'{t}'" for t in group["task"])
        parts.append(
            f"participant {p}: {names}" + ("" if left else " (so the participant is left out entirely)")
        )
    return (
        " Only the tasks a participant has in every strategy × attempt cell are averaged (a task missing "
        "for one strategy would pass for a strategy effect); left out for this reason: "
        + "; ".join(parts)
        + "."
    )


def _place(staging: Path, target: Path) -> Path:
    """Renames the finished `staging` folder to `target`, or to the first free `target-2`,
    `target-3`, ... if it exists (an empty folder counts as free): nothing is overwritten."""
    k = 1
    while True:
        candidate = target if k == 1 else target.with_name(f"{target.name}-{k}")
        k += 1
        if candidate.exists() and not (candidate.is_dir() and not any(candidate.iterdir())):
            continue
        try:
            os.rename(staging, candidate)  # atomic; fails on a non-empty folder or a file
        except OSError as e:
            if e.errno in (errno.EEXIST, errno.ENOTEMPTY, errno.ENOTDIR, errno.EISDIR):
                continue  # taken in the meantime
            raise
        return candidate


def write_report(
    run_dir: str | Path,
    out: str | Path | None = None,
    *,
    questionnaire: str | Path | None = None,
    participant: int | None = None,
    task: str | None = None,
) -> Path:
    """Analyses the study in `run_dir` and writes the report into a new folder, `out` (default
    ``RUN_DIR/report``) or, if that exists, ``OUT-2``, ``OUT-3``, ...; returns the path of report.md.

    `questionnaire`: a Table 1 answers CSV (default: ``RUN_DIR/questionnaire.csv`` if present).
    `participant`, `task`: the sample shown in the path figure (default: participant 1, laptop); a
    participant or task the study does not have is a :class:`StudyConfigError`."""
    run_dir = Path(run_dir)
    found = read_manifest(run_dir)
    if found is None:
        raise StudyFileError(
            f"{run_dir}: no study.json; not a phri study folder (run `phri study {run_dir}` first)"
        )
    config, manifest = found
    _check_sample(config, participant, task)
    if questionnaire is not None and not Path(questionnaire).exists():
        raise StudyFileError(f"{questionnaire}: questionnaire file not found")
    raw = load_results(run_dir)
    target = Path(out) if out is not None else run_dir / "report"
    target.parent.mkdir(parents=True, exist_ok=True)
    # Not tempfile.mkdtemp: its folder is private (0700); this one gets the usual permissions.
    staging = target.parent / f".{target.name}.partial-{os.getpid()}-{secrets.token_hex(4)}"
    staging.mkdir()
    try:
        _write(staging, run_dir, config, manifest, raw, questionnaire, participant, task)
        final = _place(staging, target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return final / "report.md"


@dataclass
class _Statistics:
    """The analysed tables of a study: the completed episodes and their statistics."""

    data: pd.DataFrame
    #: The completed episodes of the experimental tasks (familiarization left out).
    experimental: pd.DataFrame
    descriptives: pd.DataFrame
    pooled: pd.DataFrame
    rm: pd.DataFrame
    #: The (participant, task) pairs the repeated-measures ANOVA left out.
    unmatched: pd.DataFrame
    by_task: pd.DataFrame


def _statistics(raw: pd.DataFrame, config: StudyConfig) -> _Statistics:
    """Descriptives, the pooled and the repeated-measures ANOVAs, and the per-task tests."""
    data = analysis.prepare(raw)
    fam = config.familiarization
    experimental = data[data["task"] != fam] if fam is not None else data
    pooled = pd.concat(
        [analysis.factorial_anova(experimental, m) for m in analysis.MEASURES], ignore_index=True
    )
    rm = pd.concat([analysis.rm_anova(experimental, m) for m in analysis.MEASURES], ignore_index=True)
    _, unmatched = analysis.matched_tasks(experimental)
    return _Statistics(
        data, experimental, analysis.descriptives(data), pooled, rm, unmatched, analysis.task_tests(data)
    )


def _write_tables(out: Path, stats: _Statistics) -> None:
    """The statistics as CSV files."""
    stats.descriptives.to_csv(out / "descriptives.csv", index=False)
    stats.pooled.to_csv(out / "anova_pooled.csv", index=False)
    stats.rm.to_csv(out / "anova_rm.csv", index=False)
    stats.by_task.to_csv(out / "anova_by_task.csv", index=False)


def _introduction(
    run_dir: Path, config: StudyConfig, manifest: dict[str, Any], raw: pd.DataFrame
) -> list[str]:
    """The report's title, what the study is, how many episodes it has, and the measures."""
    fam = config.familiarization
    n_total, n_done, n_failed = config.episodes, len(raw), int((raw["status"] != "ok").sum())
    return [
        "# phri study report",
        "",
        f"Study folder `{run_dir}`: {config.participants} simulated participants, strategies "
        f"{', '.join(config.strategies)} (within subjects, order counterbalanced), tasks "
        f"{', '.join(config.tasks)} ({'familiarization: ' + fam if fam else 'no familiarization task'}), "
        f"{config.attempts} attempt(s) each, seed {config.seed}"
        + (f", duration overridden to {config.duration:g} s" if config.duration else "")
        + (f", {config.waypoints} plan waypoints" if config.waypoints else "")
        + "."
        + (
            f" **Mixed versions**: started with phri {manifest.get('phri_version')}, resumed with phri "
            f"{', '.join(map(str, resumed))}."
            if (resumed := manifest.get("resumed_with"))
            else ""
        ),
        "",
        f"Episodes: {n_done} of {n_total} recorded"
        + (f", {n_failed} failed (left out)" if n_failed else "")
        + "."
        + (
            ""
            if n_done == n_total
            else " **The study is incomplete: rerun `phri study` on the folder to finish it.**"
        ),
        "",
        "## Measures",
        "",
        "- **Effort**: Σ over interaction samples of Σ_j |u_H,j| [N·m] (the measured joint torques while the "
        "robot detects an interaction, 10 Hz).",
        "- **Interaction time**: number of interaction samples × the sample period [s].",
        "- **Cost**: the task feature's unweighted count over the executed path; **desired cost**: the same "
        "for the desired behaviour (the plan for the true weights). The statistics use the cost *relative to "
        "the desired one*, |cost − desired cost| (the paper's footnote 2).",
        "",
    ]


def _statistics_md(stats: _Statistics, config: StudyConfig) -> list[str]:
    """The statistics sections: descriptives, the pooled, repeated-measures and per-task ANOVAs."""
    exp_tasks = [t for t in dict.fromkeys(stats.data["task"]) if t != config.familiarization]
    by_task = stats.by_task
    return [
        "## Per task and strategy (mean ± SD)",
        "",
        _descriptives_md(stats.descriptives),
        "## Factorial ANOVA over pooled trials (the paper's analysis)",
        "",
        f"Strategy × attempt as between factors over the {len(stats.experimental)} pooled trials of the "
        f"tasks {', '.join(exp_tasks)} (familiarization left out), statsmodels OLS with type II sums of "
        f"squares; it treats one participant's trials as independent. {_pooled_form(stats.pooled)}",
        "",
        _anova_md(stats.pooled),
        "## Repeated-measures ANOVA (participant as the subject)",
        "",
        "statsmodels `AnovaRM`, strategy × attempt within participants, each participant's trials averaged "
        "over the experimental tasks: F(1, P − 1). Partial η² = F·df1 / (F·df1 + df2)."
        + _matching_note(stats.unmatched, stats.experimental),
        "",
        _anova_md(stats.rm),
        "### Per task",
        "",
        "The same repeated-measures ANOVA within each task; its strategy effect gives the asterisks "
        "(p < 0.0001) of the figures.",
        "",
        _anova_md(by_task[by_task["effect"] == "strategy"]) if len(by_task) else _anova_md(by_task),
    ]


def _figures(
    out: Path,
    run_dir: Path,
    config: StudyConfig,
    raw: pd.DataFrame,
    stats: _Statistics,
    participant: int | None,
    task: str | None,
) -> list[str]:
    """Draws Fig. 4 and Fig. 5 into `out`; returns the report's figures section."""
    lines = ["## Figures", ""]
    fam = config.familiarization
    if len(stats.data):
        fig4 = figures.plot_effort_time(
            stats.descriptives, out / "fig4_effort_time.png", tests=stats.by_task, familiarization=fam
        )
        fig5 = figures.plot_cost(
            stats.descriptives, out / "fig5_cost.png", tests=stats.by_task, familiarization=fam
        )
        lines += [
            f"![Effort and interaction time]({fig4.name})",
            "",
            "**Fig. 4** Effort and interaction time by task and strategy (mean ± SD).",
            "",
            f"![Cost against the desired cost]({fig5.name})",
            "",
            "**Fig. 5 (left)** Task cost of the executed path per strategy against the desired behaviour's "
            "cost.",
            "",
        ]
    else:
        lines += ["_No completed episodes yet: no figures._", ""]
    sample = _sample_logs(run_dir, raw, participant, task, config.strategies)
    if sample is None:
        who = f"participant {participant}" if participant is not None else "a sample participant"
        where = f" in task '{task}'" if task is not None else ""
        return lines + [f"_No episode logs for {who} with every strategy{where} yet: no path figure._", ""]
    p, t, logs = sample
    shown = config.load_tasks()[t]
    fig_paths = figures.plot_paths(
        logs, out / "fig5_paths.png", scene=shown.scene, task=t, keep_out=shown.keep_out_circle(t),
        frame=shown.feature_frame,
        title=f"Participant {p}, task '{t}', first attempt: executed cup path per strategy vs desired",
    )  # fmt: skip
    return lines + [
        f"![Sample participant's paths]({fig_paths.name})",
        "",
        f"**Fig. 5 (right)** Participant {p}, task '{t}', first attempt: the cup's path (link_7) with "
        "each strategy against the desired path, from the episode logs (100 Hz).",
        "",
    ]


def _questionnaire(out: Path, qpath: Path, config: StudyConfig) -> list[str]:
    """Table 1 from the answers in `qpath` (also written as table1.csv), if there are any."""
    from phri.study import questionnaire as q

    lines = ["## Questionnaire (Table 1)", ""]
    if not qpath.exists():
        return lines + [
            f"_No questionnaire answers (`{QUESTIONNAIRE_CSV}` in the study folder): simulated participants "
            "do not fill in surveys. Collect them with `phri questionnaire` or import a CSV._",
            "",
        ]
    responses = q.read_responses(qpath)
    t1 = q.table1(responses, config.strategies)
    t1.to_csv(out / "table1.csv", index=False)
    return lines + [
        f"From `{qpath}` ({len(responses)} questionnaires, {responses['participant'].nunique()} "
        f"participants). Items {', '.join(map(str, q.REVERSED))} are reverse-scored (8 − x), so higher "
        "is better on every scale; a scale's score is the mean of its items. Cronbach's α as Hoyt's "
        "ANOVA reliability (statsmodels); one-way repeated-measures ANOVA per scale (statsmodels "
        "AnovaRM).",
        "",
        q.table1_markdown(t1, config.strategies),
    ]


def _write(
    out: Path,
    run_dir: Path,
    config: StudyConfig,
    manifest: dict[str, Any],
    raw: pd.DataFrame,
    questionnaire: str | Path | None,
    participant: int | None,
    task: str | None,
) -> None:
    """Writes every file of the report into the (new, empty) folder `out`: the statistics as CSV,
    the figures, and report.md."""
    stats = _statistics(raw, config)
    _write_tables(out, stats)
    qpath = Path(questionnaire) if questionnaire is not None else run_dir / QUESTIONNAIRE_CSV
    lines = [
        *_introduction(run_dir, config, manifest, raw),
        *_statistics_md(stats, config),
        *_figures(out, run_dir, config, raw, stats, participant, task),
        *_questionnaire(out, qpath, config),
        "## Files",
        "",
        "`descriptives.csv`, `anova_pooled.csv`, `anova_rm.csv`, `anova_by_task.csv`"
        + (", `table1.csv`" if qpath.exists() else "")
        + ": the tables above. The per-episode table is the study folder's `results.csv` / "
        "`results.parquet`.",
        "",
    ]
    (out / "report.md").write_text("\n".join(lines), encoding="utf-8")
