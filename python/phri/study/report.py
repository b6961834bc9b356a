"""``phri report RUN_DIR``: the statistics, the figures and a Markdown report of a study folder.

Writes a new folder ``RUN_DIR/report/`` (or `out`): ``report.md``, the figures as PNG and PDF, and
the tables behind them as CSV (the numbers) and LaTeX (``.tex``: the cells as the report shows them).
Tests that are not estimable are reported so, never as a number, and a design too small to test
gets a warning (in the report and on the ``phri.study.report`` logger). If that folder exists (an
earlier report, perhaps edited by hand) it is left as it is and the report goes to ``report-2``,
``report-3``, ...: written once, a report is never overwritten. The report is written into a hidden
sibling folder renamed into place when complete, so a failing report leaves nothing behind. The
study's own files are only read.
"""

from __future__ import annotations

import errno
import logging
import os
import secrets
import shutil
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from phri._extras import check_part, require
from phri.atomic import write_atomic
from phri.study import analysis, figures, latex, markdown
from phri.study.errors import StudyConfigError, StudyFileError
from phri.study.markdown import NOT_ESTIMABLE, number, p_value
from phri.study.protocol import StudyConfig
from phri.study.results import load_results, read_manifest
from phri.study.targets import MEASURES, Targets, compare, read_targets

if TYPE_CHECKING:
    import pandas as pd
else:
    pd = require("pandas", __name__)

__all__ = ["MIN_PARTICIPANTS", "QUESTIONNAIRE_CSV", "write_report"]

logger = logging.getLogger(__name__)

#: Where a study folder keeps its questionnaire answers (see phri.study.questionnaire).
QUESTIONNAIRE_CSV = "questionnaire.csv"
#: Fewer participants than this are too few to test: the repeated-measures ANOVA's F(df1, P − 1)
#: would rest on a single error degree of freedom (F(1, 1)) or none.
MIN_PARTICIPANTS = 3

#: A table as the report shows it: column titles and formatted cells (written as Markdown and LaTeX).
Cells = tuple[list[str], list[list[str]]]


def _cells(table: pd.DataFrame, formats: dict[str, Callable[[object], str]] | None = None) -> Cells:
    """`table`'s column titles and cells; `formats` by column (default: strings as they are, numbers
    as :func:`markdown.number`)."""
    formats = formats or {}

    def cell(column: str, value: object) -> str:
        if column in formats:
            return formats[column](value)
        return value if isinstance(value, str) else number(value)

    rows = [[cell(c, row[c]) for c in table.columns] for _, row in table.iterrows()]
    return [str(c) for c in table.columns], rows


def _md(table: pd.DataFrame, formats: dict[str, Callable[[object], str]] | None = None) -> str:
    """`table` as Markdown (see :func:`_cells`)."""
    return markdown.table(*_cells(table, formats))


def _f_cell(r: Any) -> str:
    """An ANOVA row's "F(df1, df2) = F", or that it is not estimable (never a number then)."""
    form = f"F({r.df1:g}, {r.df2:g})"
    return f"{form} = {number(r.F, 2)}" if bool(r.estimable) else f"{form}: {NOT_ESTIMABLE}"


def _anova_cells(table: pd.DataFrame) -> Cells:
    """An ANOVA table's cells: task (if any), measure, effect, F(df1, df2), p, partial η²."""
    t = table.copy()
    t.insert(0, "F(df1, df2)", [_f_cell(r) for r in t.itertuples()])
    t["measure"] = t["measure"].map(lambda m: analysis.MEASURES.get(m, m))
    cols = [c for c in ("task", "measure", "effect", "F(df1, df2)", "p", "partial_eta_sq") if c in t]
    return _cells(
        t[cols].rename(columns={"partial_eta_sq": "partial η²"}), {"p": p_value, "F(df1, df2)": str}
    )


def _anova_md(table: pd.DataFrame) -> str:
    if not len(table):
        return "_Not enough data (needs at least two levels of a factor, and two complete participants)._\n"
    text = markdown.table(*_anova_cells(table))
    if not table["estimable"].all():
        text += (
            f"\n_{NOT_ESTIMABLE.capitalize()}: the test's error term has no variance (every participant's "
            "value is the same in each cell, up to rounding), so its F would be 0/0 or x/0 in floating "
            "point, not a statistic._\n"
        )
    return text


def _descriptives_cells(desc: pd.DataFrame) -> Cells | None:
    """The descriptives as the report shows them (mean ± SD), or None without completed episodes."""
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
    return _cells(pd.DataFrame(rows), {c: str for c in rows[0]}) if rows else None


def _descriptives_md(desc: pd.DataFrame) -> str:
    cells = _descriptives_cells(desc)
    return markdown.table(*cells) if cells is not None else "_No completed episodes._\n"


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


def _remove_stale_staging(target: Path) -> None:
    """Removes the staging folders of reports into `target` whose process is gone (killed mid-way);
    a running report's folder is left alone."""
    for folder in target.parent.glob(f".{target.name}.partial-*-*"):
        pid = folder.name.rsplit("-", 2)[-2]
        if not pid.isdigit():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(folder, ignore_errors=True)
        except OSError:
            pass  # another user's process: alive


def write_report(
    run_dir: str | Path,
    out: str | Path | None = None,
    *,
    questionnaire: str | Path | None = None,
    participant: int | None = None,
    task: str | None = None,
    reference: str | Path | None = None,
) -> Path:
    """Analyses the study in `run_dir` and writes the report into a new folder, `out` (default
    ``RUN_DIR/report``) or, if that exists, ``OUT-2``, ``OUT-3``, ...; returns the path of report.md.

    `questionnaire`: a Table 1 answers CSV (default: ``RUN_DIR/questionnaire.csv`` if present).
    `participant`, `task`: the sample shown in the path figure (default: participant 1, laptop); a
    participant or task the study does not have is a :class:`StudyConfigError`; without the
    ``phri[study]`` extra, a :class:`~phri.exceptions.MissingExtraError`. `reference`: a reference
    statistics CSV (:mod:`phri.study.targets`) or a shipped reference's name; the report then compares
    each of its cells with the study's (simulated, reference, ratio), also as ``reference.csv``."""
    check_part("the report")  # before any work (pandas was needed to import this module)
    run_dir = Path(run_dir)
    found = read_manifest(run_dir)
    if found is None:
        raise StudyFileError(
            f"{run_dir}: no study.json; not a phri study folder (run `phri study {run_dir}` first)"
        )
    config, manifest = found
    _check_sample(config, participant, task)
    targets = None
    if reference is not None:
        targets = read_targets(reference)
        targets.check_tasks(config.task_names(), "the study's tasks")
    if questionnaire is not None and not Path(questionnaire).exists():
        raise StudyFileError(f"{questionnaire}: questionnaire file not found")
    raw = load_results(run_dir)
    target = Path(out) if out is not None else run_dir / "report"
    target.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_staging(target)
    # Not tempfile.mkdtemp: its folder is private (0700); this one gets the usual permissions.
    staging = target.parent / f".{target.name}.partial-{os.getpid()}-{secrets.token_hex(4)}"
    staging.mkdir()
    try:
        _write(staging, run_dir, config, manifest, raw, questionnaire, participant, task, targets)
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


def _write_table(out: Path, name: str, table: pd.DataFrame, cells: Cells | None) -> list[str]:
    """Writes `table` as ``NAME.csv`` (its numbers) and, if it has `cells`, ``NAME.tex`` (them as the
    report shows them), each atomically; returns the files' names."""
    write_atomic(out / f"{name}.csv", table.to_csv(index=False).encode("utf-8"))
    if cells is None:
        return [f"{name}.csv"]
    write_atomic(out / f"{name}.tex", latex.table(*cells).encode("utf-8"))
    return [f"{name}.csv", f"{name}.tex"]


def _write_tables(out: Path, stats: _Statistics) -> list[str]:
    """The statistics as CSV and LaTeX files; returns their names."""
    return [
        *_write_table(out, "descriptives", stats.descriptives, _descriptives_cells(stats.descriptives)),
        *(
            name
            for key, table in (("pooled", stats.pooled), ("rm", stats.rm), ("by_task", stats.by_task))
            for name in _write_table(out, f"anova_{key}", table, _anova_cells(table) if len(table) else None)
        ),
    ]


def _design_warnings(stats: _Statistics, config: StudyConfig) -> list[str]:
    """Why the tests of this study say little or nothing, if they do: too few participants, too few
    error degrees of freedom, tests that are not estimable."""
    out = []
    small = config.participants < MIN_PARTICIPANTS
    if small:
        out.append(
            f"The study has {config.participants} participant(s), fewer than {MIN_PARTICIPANTS}: too few "
            f"to test. The repeated-measures ANOVAs have F(df1, P − 1) = F(·, {config.participants - 1}) "
            "at best, and the pooled ANOVA treats one participant's trials as independent; read the "
            "p-values as a description of these runs, not as evidence."
        )
    analyses = {"pooled factorial ANOVA": stats.pooled, "repeated-measures ANOVA": stats.rm,
                "per-task repeated-measures ANOVA": stats.by_task}  # fmt: skip
    for name, table in analyses.items():
        if small and name != "pooled factorial ANOVA":
            continue  # said above
        few = table[table["df2"] < 2] if len(table) else table
        if len(few):
            forms = " and ".join(sorted({f"F({r.df1:g}, {r.df2:g})" for r in few.itertuples()}))
            out.append(
                f"The {name} has {forms}: with fewer than 2 error degrees of freedom a test has "
                "almost no power and its p-value rests on one residual or none."
            )
    tests = [t for t in analyses.values() if len(t)]
    n_tests = sum(len(t) for t in tests)
    n_not = sum(int((~t["estimable"].astype(bool)).sum()) for t in tests)
    if n_not:
        out.append(
            f"{n_not} of the {n_tests} tests {'is' if n_not == 1 else 'are'} {NOT_ESTIMABLE} (their error "
            "term has no variance: "
            "every participant's value is the same in each cell, up to rounding); they are marked so "
            "and never get a significance asterisk."
        )
    return out


def _log_warnings(run_dir: Path, raw: pd.DataFrame) -> list[str]:
    """Recorded episodes whose log is missing: the table still has their row."""
    named = [str(log) for log in raw["log"] if isinstance(log, str) and log]
    missing = [log for log in named if not (run_dir / log).is_file()]
    if not missing:
        return []
    shown = ", ".join(f"`{m}`" for m in missing[:5]) + (
        f" and {len(missing) - 5} more" if len(missing) > 5 else ""
    )
    return [
        f"{len(missing)} of the {len(named)} recorded episodes have no log in the study folder ({shown}): "
        "their rows are analysed, but no figure can show them."
    ]


#: The report's replays: one page per episode with a log, sharing the scripts in REPLAYS/viewer.
REPLAYS = "replays"


def _replays(out: Path, run_dir: Path, raw: pd.DataFrame) -> list[str]:
    """Writes a replay page (:mod:`phri.view`) per recorded episode with a log into
    ``out/replays``; returns the report's section linking to them."""
    from phri.exceptions import LogError
    from phri.view import StudyEpisode, replay_page, write_scripts

    scripts = "viewer"  # the pages' shared scripts, in REPLAYS/viewer
    rows, skipped = [], []
    (out / REPLAYS).mkdir()
    for r in raw.sort_values(["participant", "task", "strategy", "attempt"]).itertuples():
        log = str(r.log) if isinstance(r.log, str) else ""
        if not log or not (run_dir / log).is_file():
            continue
        e = StudyEpisode(int(r.participant), str(r.task), str(r.strategy), int(r.attempt), str(r.status),
                         (run_dir / log).resolve())  # fmt: skip
        try:
            page = replay_page(e.log, title=e.title, scripts=scripts)
        except LogError as err:
            skipped.append(f"`{log}` ({err})")
            continue
        write_atomic(out / REPLAYS / f"{e.name}.html", page.encode("utf-8"))
        rows.append(f"| {e.participant} | {e.task} | {e.strategy} | {e.attempt} | {e.status} | "
                    f"[replay]({REPLAYS}/{e.name}.html) |")  # fmt: skip
    if rows:
        write_scripts(out / REPLAYS / scripts)
    lines = ["## Episode replays", ""]
    if rows:
        lines += [
            "Each episode in 3D, with its plots (`phri view` serves the same pages; "
            "open one at a time with `?t=SECONDS` after its address).", "",
            "| participant | task | strategy | attempt | status | |", "|---|---|---|---|---|---|", *rows, "",
        ]  # fmt: skip
    else:
        lines += ["No episode has a log to replay.", ""]
    if skipped:
        logs = f"{len(skipped)} log" + ("s" if len(skipped) != 1 else "")
        lines += [
            f"No replay for {logs}: " + "; ".join(skipped[:3]) + (" ..." if len(skipped) > 3 else ""),
            "",
        ]
    return lines


def _html(text: str) -> str:
    """The Markdown report `text` as a standalone HTML page (Python-Markdown, with its tables)."""
    markdown_lib = require("markdown", "the HTML report")
    body = markdown_lib.markdown(text, extensions=["tables"], output_format="html")
    return (
        '<!doctype html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        "<title>phri study report</title>\n<style>\n"
        "body { font-family: system-ui, sans-serif; max-width: 60em; margin: 2em auto; padding: 0 1em;"
        " line-height: 1.45; color: #222; }\n"
        "table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.92em; }\n"
        "th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; }\n"
        "th { background: #f0f3f6; } img { max-width: 100%; } code { background: #f4f4f4; }\n"
        "</style>\n</head>\n<body>\n" + body + "\n</body>\n</html>\n"
    )


def _warnings_md(warnings: list[str]) -> list[str]:
    """The report's warnings section, if there are warnings."""
    if not warnings:
        return []
    return ["## Warnings", "", *(f"- **Warning**: {w}" for w in warnings), ""]


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
        + (f", plans by {config.knots} knots" if config.knots else "")
        + (", plans on every waypoint" if config.knots == 0 else "")
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
        f"robot detects an interaction, sampled at {config.sample_rate:g} Hz).",
        "- **Interaction time**: number of interaction samples × the sample period "
        f"(1/{config.sample_rate:g} Hz = {1.0 / config.sample_rate:g} s) [s].",
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


#: What reading a damaged .npz log raises: truncated or empty (BadZipFile, EOFError, OSError), wrong
#: keys (KeyError), wrong shapes or NaN (ValueError, IndexError).
DAMAGED_LOG = (zipfile.BadZipFile, EOFError, OSError, KeyError, ValueError, IndexError)


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
            f"**Fig. 4** Effort and interaction time by task and strategy (mean ± SD). Also as "
            f"`{fig4.with_suffix('.pdf').name}`.",
            "",
            f"![Cost against the desired cost]({fig5.name})",
            "",
            "**Fig. 5 (left)** Task cost of the executed path per strategy against the desired behaviour's "
            f"cost. Also as `{fig5.with_suffix('.pdf').name}`.",
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
    try:
        fig_paths = figures.plot_paths(
            logs, out / "fig5_paths.png", scene=shown.scene, task=t, keep_out=shown.keep_out_circle(t),
            frame=shown.feature_frame, robot=shown.robot,
            title=f"Participant {p}, task '{t}', first attempt: executed cup path per strategy vs desired",
        )  # fmt: skip
        rate = figures.log_rate(next(iter(logs.values())))
    except DAMAGED_LOG as e:
        # One damaged log: the rest of the report stands, naming the file.
        named = ", ".join(f"`{log.relative_to(run_dir)}`" for log in logs.values())
        logger.warning("%s: an episode log of %s cannot be read: %s", run_dir, named, e)
        return lines + [
            f"_An episode log among {named} is damaged ({type(e).__name__}: {e}): no path figure._",
            "",
        ]
    return lines + [
        f"![Sample participant's paths]({fig_paths.name})",
        "",
        f"**Fig. 5 (right)** Participant {p}, task '{t}', first attempt: the cup's path (link_7) with "
        f"each strategy against the desired path, from the episode logs ({rate:.4g} Hz). Also as "
        f"`{fig_paths.with_suffix('.pdf').name}`.",
        "",
    ]


def _questionnaire(out: Path, qpath: Path, config: StudyConfig) -> list[str]:
    """Table 1 from the answers in `qpath` (also written as table1.csv and table1.tex), if there
    are any."""
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
    _write_table(out, "table1", t1, q.table1_cells(t1, config.strategies))
    return lines + [
        f"From `{qpath}` ({len(responses)} questionnaires, {responses['participant'].nunique()} "
        f"participants). Items {', '.join(map(str, q.REVERSED))} are reverse-scored (8 − x), so higher "
        "is better on every scale; a scale's score is the mean of its items. Cronbach's α as Hoyt's "
        "ANOVA reliability (statsmodels); one-way repeated-measures ANOVA per scale (statsmodels "
        "AnovaRM).",
        "",
        q.table1_markdown(t1, config.strategies),
    ]


def _reference(out: Path, targets: Targets, stats: _Statistics, config: StudyConfig) -> list[str]:
    """The comparison with the reference statistics: a Markdown section, also as reference.csv."""
    rows = compare(targets, stats.data, config.sample_rate)
    table = pd.DataFrame(rows, columns=["task", "strategy", "statistic", "reference", "simulated", "ratio"])
    write_atomic(out / "reference.csv", table.to_csv(index=False).encode("utf-8"))
    shown = table.copy()
    shown["statistic"] = [
        f"{s} [{MEASURES[s]}]" if s in MEASURES else s.replace("_sd", " SD") for s in shown["statistic"]
    ]
    pooled = list(targets.pooled)
    note = (
        " A pooled row is the strategy effect's F in the factorial ANOVA over those tasks' trials (the "
        f"reference's F(1, {pooled[0].df_error:g}) against this study's)."
        if pooled
        else ""
    )
    return [
        "## Against the reference",
        "",
        f"Reference statistics `{targets.source}`: per task and strategy the mean (and SD where given) of "
        "the simulated trials against the reference, and their ratio (simulated / reference). Effort per "
        "sample is the mean effort over the mean number of interaction samples." + note,
        "",
        _md(shown, {"ratio": lambda v: number(v, 2)}),
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
    targets: Targets | None = None,
) -> None:
    """Writes every file of the report into the (new, empty) folder `out`: the statistics as CSV and
    LaTeX, the figures as PNG and PDF, and report.md (each file atomically)."""
    stats = _statistics(raw, config)
    tables = _write_tables(out, stats)
    reference_lines = [] if targets is None else _reference(out, targets, stats, config)
    if targets is not None:
        tables.append("reference.csv")
    warnings = [*_design_warnings(stats, config), *_log_warnings(run_dir, raw)]
    for w in warnings:
        logger.warning("%s: %s", run_dir, w)
    qpath = Path(questionnaire) if questionnaire is not None else run_dir / QUESTIONNAIRE_CSV
    lines = [
        *_introduction(run_dir, config, manifest, raw),
        *_warnings_md(warnings),
        *_statistics_md(stats, config),
        *reference_lines,
        *_figures(out, run_dir, config, raw, stats, participant, task),
        *_questionnaire(out, qpath, config),
        *_replays(out, run_dir, raw),
    ]
    if qpath.exists():
        tables += ["table1.csv", "table1.tex"]
    lines += [
        "## Files",
        "",
        ", ".join(f"`{name}`" for name in tables)
        + ": the tables above, as CSV (the numbers) and LaTeX (the cells as shown here; needs booktabs). "
        "The figures are PNG and PDF files of the same names. The per-episode table is the study "
        "folder's `results.csv` (and `results.parquet` where the `phri[parquet]` extra is installed).",
        "",
    ]
    text = "\n".join(lines)
    write_atomic(out / "report.md", text.encode("utf-8"))
    write_atomic(out / "report.html", _html(text).encode("utf-8"))
