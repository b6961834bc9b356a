"""``phri report RUN_DIR``: the statistics, the figures and a Markdown report of a study folder.

Writes into ``RUN_DIR/report/`` (or `out`): ``report.md``, the PNG figures, and the tables behind
them as CSV. Everything there is derived from the study folder and is rewritten on each call; the
study's own files are only read.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from phri.study import analysis, figures
from phri.study.errors import StudyFileError
from phri.study.results import load_results, read_manifest

__all__ = ["QUESTIONNAIRE_CSV", "write_report"]

#: Where a study folder keeps its questionnaire answers (see phri.study.questionnaire).
QUESTIONNAIRE_CSV = "questionnaire.csv"


def _fmt(x: object, digits: int = 3) -> str:
    try:
        v = float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return str(x)
    if not np.isfinite(v):
        return "—"
    if v != 0 and (abs(v) >= 1e5 or abs(v) < 10**-(digits)):
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}f}"


def _p(p: object) -> str:
    p = float(p)  # type: ignore[arg-type]
    return "—" if not np.isfinite(p) else ("< .0001" if p < 1e-4 else f"{p:.4f}")


def _md(table: pd.DataFrame, formats: dict[str, Callable[[object], str]] | None = None) -> str:
    formats = formats or {}
    head = [str(c) for c in table.columns]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, row in table.iterrows():
        cells = [
            formats.get(c, lambda v: v if isinstance(v, str) else _fmt(v))(row[c]) for c in table.columns
        ]
        lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines) + "\n"


def _anova_md(table: pd.DataFrame) -> str:
    if not len(table):
        return "_Not enough data (needs at least two levels of a factor, and two complete participants)._\n"
    t = table.copy()
    t.insert(0, "F(df1, df2)", [f"F({r.df1:g}, {r.df2:g}) = {_fmt(r.F, 2)}" for r in t.itertuples()])
    t["measure"] = t["measure"].map(lambda m: analysis.MEASURES.get(m, m))
    cols = [c for c in ("task", "measure", "effect", "F(df1, df2)", "p", "partial_eta_sq") if c in t]
    return _md(t[cols].rename(columns={"partial_eta_sq": "partial η²"}), {"p": _p, "F(df1, df2)": str})


def _descriptives_md(desc: pd.DataFrame) -> str:
    rows = []
    for r in desc.itertuples():
        rows.append({
            "task": r.task, "strategy": r.strategy, "n": str(r.n),
            "effort [N·m]": f"{_fmt(r.effort_mean, 1)} ± {_fmt(r.effort_sd, 1)}",
            "interaction time [s]": f"{_fmt(r.interaction_time_mean, 2)} ± {_fmt(r.interaction_time_sd, 2)}",
            "cost": f"{_fmt(r.cost_mean)} ± {_fmt(r.cost_sd)}",
            "desired cost": _fmt(r.desired_cost_mean),
            "abs(cost − desired)": f"{_fmt(r.cost_error_mean)} ± {_fmt(r.cost_error_sd)}",
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


def write_report(
    run_dir: str | Path,
    out: str | Path | None = None,
    *,
    questionnaire: str | Path | None = None,
    participant: int | None = None,
    task: str | None = None,
) -> Path:
    """Analyses the study in `run_dir` and writes the report; returns the path of report.md.

    `questionnaire`: a Table 1 answers CSV (default: ``RUN_DIR/questionnaire.csv`` if present).
    `participant`, `task`: the sample shown in the path figure (default: participant 1, laptop)."""
    from phri.study import questionnaire as q

    run_dir = Path(run_dir)
    found = read_manifest(run_dir)
    if found is None:
        raise StudyFileError(
            f"{run_dir}: no study.json; not a phri study folder (run `phri study {run_dir}` first)"
        )
    config, _ = found
    raw = load_results(run_dir)
    out = Path(out) if out is not None else run_dir / "report"
    out.mkdir(parents=True, exist_ok=True)
    data = analysis.prepare(raw)
    fam = config.familiarization
    experimental = data[data["task"] != fam] if fam is not None else data
    desc = analysis.descriptives(data)
    pooled = pd.concat(
        [analysis.factorial_anova(experimental, m) for m in analysis.MEASURES], ignore_index=True
    )
    rm = pd.concat([analysis.rm_anova(experimental, m) for m in analysis.MEASURES], ignore_index=True)
    by_task = analysis.task_tests(data)
    desc.to_csv(out / "descriptives.csv", index=False)
    pooled.to_csv(out / "anova_pooled.csv", index=False)
    rm.to_csv(out / "anova_rm.csv", index=False)
    by_task.to_csv(out / "anova_by_task.csv", index=False)

    n_total, n_done, n_failed = config.episodes, len(raw), int((raw["status"] != "ok").sum())
    exp_tasks = [t for t in dict.fromkeys(data["task"]) if t != fam]
    lines = [
        "# phri study report",
        "",
        f"Study folder `{run_dir}`: {config.participants} simulated participants, strategies "
        f"{', '.join(config.strategies)} (within subjects, order counterbalanced), tasks "
        f"{', '.join(config.tasks)} ({'familiarization: ' + fam if fam else 'no familiarization task'}), "
        f"{config.attempts} attempt(s) each, seed {config.seed}"
        + (f", duration overridden to {config.duration:g} s" if config.duration else "")
        + (f", {config.waypoints} plan waypoints" if config.waypoints else "")
        + ".",
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
        "## Per task and strategy (mean ± SD)",
        "",
        _descriptives_md(desc),
        "## Factorial ANOVA over pooled trials (the paper's analysis)",
        "",
        f"Strategy × attempt as between factors over the {len(experimental)} pooled trials of the tasks "
        f"{', '.join(exp_tasks)} (familiarization left out), statsmodels OLS with type II sums of squares. "
        "This is the paper's F(1, 116) form for 10 participants; it treats one participant's trials as "
        "independent.",
        "",
        _anova_md(pooled),
        "## Repeated-measures ANOVA (participant as the subject)",
        "",
        "statsmodels `AnovaRM`, strategy × attempt within participants, each participant's trials averaged "
        "over the experimental tasks: F(1, P − 1). Partial η² = F·df1 / (F·df1 + df2).",
        "",
        _anova_md(rm),
        "### Per task",
        "",
        "The same repeated-measures ANOVA within each task; its strategy effect gives the asterisks "
        "(p < 0.0001) of the figures.",
        "",
        _anova_md(by_task[by_task["effect"] == "strategy"]) if len(by_task) else _anova_md(by_task),
        "## Figures",
        "",
    ]
    if len(data):
        fig4 = figures.plot_effort_time(
            desc, out / "fig4_effort_time.png", tests=by_task, familiarization=fam
        )
        fig5 = figures.plot_cost(desc, out / "fig5_cost.png", tests=by_task, familiarization=fam)
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
    if sample is not None:
        p, t, logs = sample
        scene = config.load_tasks()[t].scene
        fig_paths = figures.plot_paths(
            logs, out / "fig5_paths.png", scene=scene, task=t,
            title=f"Participant {p}, task '{t}', first attempt: executed cup path per strategy vs desired",
        )  # fmt: skip
        lines += [
            f"![Sample participant's paths]({fig_paths.name})",
            "",
            f"**Fig. 5 (right)** Participant {p}, task '{t}', first attempt: the cup's path (link_7) with "
            "each strategy against the desired path, from the episode logs (100 Hz).",
            "",
        ]
    else:
        lines += ["_No episode logs for a sample participant with every strategy yet: no path figure._", ""]

    qpath = Path(questionnaire) if questionnaire is not None else run_dir / QUESTIONNAIRE_CSV
    lines += ["## Questionnaire (Table 1)", ""]
    if qpath.exists():
        responses = q.read_responses(qpath)
        t1 = q.table1(responses, config.strategies)
        t1.to_csv(out / "table1.csv", index=False)
        lines += [
            f"From `{qpath}` ({len(responses)} questionnaires, {responses['participant'].nunique()} "
            f"participants). Items {', '.join(map(str, q.REVERSED))} are reverse-scored (8 − x), so higher "
            "is better on every scale; a scale's score is the mean of its items. Cronbach's α as Hoyt's "
            "ANOVA reliability (statsmodels); one-way repeated-measures ANOVA per scale (statsmodels "
            "AnovaRM).",
            "",
            q.table1_markdown(t1, config.strategies),
        ]
    elif questionnaire is not None:
        raise StudyFileError(f"{qpath}: questionnaire file not found")
    else:
        lines += [
            f"_No questionnaire answers (`{QUESTIONNAIRE_CSV}` in the study folder): simulated participants "
            "do not fill in surveys. Collect them with `phri questionnaire` or import a CSV._",
            "",
        ]
    lines += [
        "## Files",
        "",
        "`descriptives.csv`, `anova_pooled.csv`, `anova_rm.csv`, `anova_by_task.csv`"
        + (", `table1.csv`" if qpath.exists() else "")
        + ": the tables above. The per-episode table is the study folder's `results.csv` / "
        "`results.parquet`.",
        "",
    ]
    report = out / "report.md"
    report.write_text("\n".join(lines), encoding="utf-8")
    return report
