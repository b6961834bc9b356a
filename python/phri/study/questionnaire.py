"""The paper's Table 1 questionnaire: ten 7-point Likert items after each strategy, four scales.

Items 2, 4, 5, 8 and 10 are negatively worded and reverse-scored (8 − x), so that higher is better on
every scale: understanding (items 1-4), effort (5-6: higher = less effort), predictability (7-8),
collaboration (9-10). Per scale:

- reliability by Cronbach's α, computed as Hoyt's ANOVA reliability 1 − MS_residual / MS_respondents
  from the respondents × items two-way ANOVA (statsmodels OLS + anova_lm), which equals Cronbach's α
  (Hoyt 1941; Cronbach 1951). Each completed questionnaire (participant × strategy) is a respondent;
- the scale score is the mean of its (reverse-scored) items;
- a one-way repeated-measures ANOVA of the score, strategy within participants (statsmodels
  AnovaRM), F(1, P − 1) as in the paper.

Responses live in a CSV with the columns ``participant,strategy,q1,...,q10`` (raw answers 1-7, not
reverse-scored), one row per participant and strategy: typed in with :func:`ask` or imported.
"""

from __future__ import annotations

import csv
import io
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from phri._extras import require
from phri._validate import decode_utf8
from phri.atomic import exclusive, write_atomic
from phri.study import markdown
from phri.study.errors import QuestionnaireError

if TYPE_CHECKING:
    import pandas as pd

    from phri.study.protocol import StudyConfig
else:
    pd = require("pandas", __name__)

__all__ = [
    "ITEMS",
    "REVERSED",
    "SCALES",
    "append_response",
    "ask",
    "check_in_study",
    "import_responses",
    "cronbach_alpha",
    "read_responses",
    "reverse_score",
    "scale_scores",
    "table1",
    "table1_cells",
    "table1_markdown",
]

#: The ten items of Table 1, in order (item i is ITEMS[i - 1]).
ITEMS: tuple[str, ...] = (
    "By the end, the robot understood how I wanted it to do the task.",
    "Even by the end, the robot still did not know how I wanted it to do the task.",
    "The robot learned from my corrections.",
    "The robot did not understand what I was trying to accomplish.",
    "I had to keep correcting the robot.",
    "The robot required minimal correction.",
    "It was easy to anticipate how the robot will respond to my corrections.",
    "The robot's response to my corrections was surprising.",
    "The robot worked with me to complete the task.",
    "The robot did not collaborate with me to complete the task.",
)
#: Negatively worded items, reverse-scored as 8 − x.
REVERSED: tuple[int, ...] = (2, 4, 5, 8, 10)
#: Scale -> its items (1-based).
SCALES: dict[str, tuple[int, ...]] = {
    "understanding": (1, 2, 3, 4),
    "effort": (5, 6),
    "predictability": (7, 8),
    "collaboration": (9, 10),
}
ITEM_COLUMNS = tuple(f"q{i}" for i in range(1, len(ITEMS) + 1))
COLUMNS = ("participant", "strategy", *ITEM_COLUMNS)
LIKERT = range(1, 8)


# -- collecting answers ---------------------------------------------------------------------------


def ask(
    participant: int,
    strategy: str,
    *,
    read: Callable[[str], str] = input,
    write: Callable[[str], object] = print,
) -> dict[str, int]:
    """Asks the ten items on the terminal; an answer outside 1-7 is asked again.
    Returns ``{"q1": x1, ..., "q10": x10}`` (raw answers)."""
    write(f"\nQuestionnaire: participant {participant}, strategy '{strategy}'.")
    write("Answer each statement from 1 (strongly disagree) to 7 (strongly agree).")
    answers: dict[str, int] = {}
    for i, (column, item) in enumerate(zip(ITEM_COLUMNS, ITEMS, strict=True), start=1):
        while True:
            try:
                text = read(f"{i:2d}. {item} [1-7]: ").strip()
            except EOFError:
                raise QuestionnaireError(
                    f"questionnaire: input ended at item {i} (participant {participant}, {strategy})"
                ) from None
            if text.isdigit() and int(text) in LIKERT:
                answers[column] = int(text)
                break
            write("   please type a whole number from 1 to 7")
    return answers


def check_in_study(
    participant: int,
    strategy: str,
    study: StudyConfig,
    where: str,
    names: tuple[str, str] = ("column 'participant'", "column 'strategy'"),
) -> None:
    """Raises unless `participant` and `strategy` are among the study's: an answer for a participant
    or strategy the study does not have would make every later report fail. `names` name the two
    fields in the message."""
    if not 1 <= participant <= study.participants:
        raise QuestionnaireError(
            f"{where}: {names[0]} must be one of the study's participants 1-{study.participants}, "
            f"got {participant}"
        )
    if strategy not in study.strategies:
        raise QuestionnaireError(
            f"{where}: {names[1]} must be one of the study's strategies {list(study.strategies)}, "
            f"got {strategy!r}"
        )


def append_response(
    path: str | Path,
    participant: int,
    strategy: str,
    answers: Mapping[str, int],
    *,
    study: StudyConfig | None = None,
) -> None:
    """Appends one questionnaire to the CSV `path` (created with its header if missing). A second
    answer for the same participant and strategy is refused, and with `study` a participant or
    strategy that is not the study's; nothing written is changed."""
    path = Path(path)
    row = {"participant": participant, "strategy": strategy, **answers}
    _validate_row(row, f"{path}: new row")
    if study is not None:
        check_in_study(participant, strategy, study, f"{path}: new row")
    with exclusive(path):  # a concurrent import or answer waits: no row is lost
        existing = read_responses(path) if path.exists() else None
        if existing is not None:
            clash = (existing["participant"] == participant) & (existing["strategy"] == strategy)
            if clash.any():
                raise QuestionnaireError(
                    f"{path}: participant {participant} already answered for '{strategy}'"
                )
        _append_rows(path, [row])


def _append_rows(path: Path, rows: Sequence[Mapping[str, object]]) -> None:
    """Adds `rows` to `path` all at once: the file is replaced by its old bytes plus the new rows (a
    temporary file renamed into place), so a failure leaves it as it was."""
    old = path.read_bytes() if path.exists() else (",".join(COLUMNS) + "\n").encode()
    if old and not old.endswith(b"\n"):
        old += b"\n"
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    for row in rows:
        writer.writerow([row[c] for c in COLUMNS])
    write_atomic(path, old + buffer.getvalue().encode("utf-8"))


def import_responses(source: str | Path, target: str | Path, *, study: StudyConfig | None = None) -> int:
    """Appends the questionnaires of the CSV `source` to `target`; returns how many were new. Answers
    already in `target` are skipped if identical. A conflicting answer, or with `study` a participant
    or strategy that is not the study's, is an error raised before anything is written: the import
    is all or nothing."""
    incoming = read_responses(source)
    target = Path(target)
    with exclusive(target):  # a concurrent import or answer waits: no row is lost
        return _import_rows(source, incoming, target, study)


def _import_rows(source: str | Path, incoming: pd.DataFrame, target: Path, study: StudyConfig | None) -> int:
    """import_responses with the target locked."""
    existing = read_responses(target) if target.exists() else pd.DataFrame(columns=list(COLUMNS))
    known = {(int(r["participant"]), str(r["strategy"])): r for r in existing.to_dict("records")}
    new = []
    for n, row in zip(incoming.attrs["lines"], incoming.to_dict("records"), strict=True):
        key = (int(row["participant"]), str(row["strategy"]))
        if study is not None:
            check_in_study(key[0], key[1], study, f"{source}: line {n}")
        if key in known:
            if any(int(known[key][c]) != int(row[c]) for c in ITEM_COLUMNS):
                raise QuestionnaireError(
                    f"{source}: line {n}: participant {key[0]} ({key[1]}) differs from the answers already "
                    f"in {target}; nothing was imported"
                )
            continue
        new.append(row)
    if new:
        _append_rows(target, new)
    return len(new)


def _validate_row(row: Mapping[str, object], where: str) -> dict[str, object]:
    out: dict[str, object] = {}
    for column in COLUMNS:
        value = row.get(column)
        if value is None or (isinstance(value, str) and not value.strip()):
            raise QuestionnaireError(f"{where}: column '{column}' is missing")
        if column == "strategy":
            out[column] = str(value).strip()
            continue
        text = str(value).strip()
        try:
            number = int(text)
        except ValueError:
            raise QuestionnaireError(
                f"{where}: column '{column}' must be a whole number, got {value!r}"
            ) from None
        if column == "participant" and number < 1:
            raise QuestionnaireError(f"{where}: column 'participant' must be >= 1 (1-based), got {number}")
        if column != "participant" and number not in LIKERT:
            raise QuestionnaireError(f"{where}: column '{column}' must be 1-7 (7-point Likert), got {number}")
        out[column] = number
    return out


def read_responses(path: str | Path) -> pd.DataFrame:
    """Reads and validates a questionnaire CSV (columns ``participant,strategy,q1..q10``; extra
    columns are ignored). Errors name the file, the line and the column."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise QuestionnaireError(f"{path}: cannot read the questionnaire file ({e.strerror})") from None
    text = decode_utf8(
        data,
        lambda line, _, bad: QuestionnaireError(
            f"{path}: line {line}: byte {bad!r} is not UTF-8 (a Latin-1 or Windows file?); save the "
            "questionnaire as CSV UTF-8"
        ),
    )
    reader = csv.DictReader(io.StringIO(text))
    missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
    if missing:
        raise QuestionnaireError(f"{path}: line 1: missing column(s) {missing}; expected {','.join(COLUMNS)}")
    rows, lines, seen = [], [], set()
    for raw in reader:
        n = reader.line_num  # the file's line (blank lines are skipped by the reader)
        row = _validate_row(raw, f"{path}: line {n}")
        key = (row["participant"], row["strategy"])
        if key in seen:
            raise QuestionnaireError(f"{path}: line {n}: participant {key[0]} answered twice for '{key[1]}'")
        seen.add(key)
        rows.append(row)
        lines.append(n)
    if not rows:
        raise QuestionnaireError(f"{path}: no responses")
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    table = table.astype({c: np.int64 for c in COLUMNS if c != "strategy"})
    table.attrs["lines"] = lines  # each row's line in the file, for error messages
    return table


# -- scoring --------------------------------------------------------------------------------------


def reverse_score(responses: pd.DataFrame) -> pd.DataFrame:
    """A copy with the negatively worded items (2, 4, 5, 8, 10) replaced by 8 − x."""
    scored = responses.copy()
    for i in REVERSED:
        scored[f"q{i}"] = 8 - scored[f"q{i}"]
    return scored


def scale_scores(responses: pd.DataFrame) -> pd.DataFrame:
    """Participant, strategy and each scale's score (mean of its reverse-scored items)."""
    scored = reverse_score(responses)
    out = scored[["participant", "strategy"]].copy()
    for scale, items in SCALES.items():
        out[scale] = scored[[f"q{i}" for i in items]].mean(axis=1)
    return out


def cronbach_alpha(items: pd.DataFrame | np.ndarray) -> float:
    """Cronbach's α of an (respondents × items) table, as Hoyt's ANOVA reliability
    1 − MS_residual / MS_respondents of the two-way ANOVA without replication (statsmodels).
    NaN when it is undefined (fewer than 2 items or respondents, or no variance between respondents)."""
    smf = require("statsmodels.formula.api", __name__)
    anova_lm = require("statsmodels.stats.anova", __name__).anova_lm

    x = np.asarray(items, dtype=float)
    if x.ndim != 2 or x.shape[0] < 2 or x.shape[1] < 2 or not np.isfinite(x).all():
        return float("nan")
    n, k = x.shape
    long = pd.DataFrame({
        "score": x.ravel(),
        "respondent": np.repeat(np.arange(n), k).astype(str),
        "item": np.tile(np.arange(k), n).astype(str),
    })  # fmt: skip
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        table = anova_lm(smf.ols("score ~ C(respondent) + C(item)", data=long).fit(), typ=2)
    ms_respondents = table.loc["C(respondent)", "sum_sq"] / table.loc["C(respondent)", "df"]
    ms_residual = table.loc["Residual", "sum_sq"] / table.loc["Residual", "df"]
    if not ms_respondents > 1e-12 * max(1.0, float(np.abs(x).max()) ** 2):
        return float("nan")
    return float(1.0 - ms_residual / ms_respondents)


def table1(responses: pd.DataFrame, strategies: Sequence[str] = ("impedance", "learning")) -> pd.DataFrame:
    """The paper's Table 1: per scale its items, Cronbach's α, the mean score per strategy (the
    least-squares means, equal to the plain means in this balanced design), and the one-way
    repeated-measures ANOVA (F, its degrees of freedom, p, partial η², and whether it is estimable:
    see :mod:`phri.study.analysis`). Participants who did not answer for every strategy are left out
    of the ANOVA only."""
    from phri.study.analysis import rm_anova

    unknown = sorted(set(responses["strategy"]) - set(strategies))
    if unknown:
        raise QuestionnaireError(f"questionnaire: strategies {unknown} are not among {list(strategies)}")
    scores = scale_scores(responses)
    scored = reverse_score(responses)
    rows = []
    for scale, items in SCALES.items():
        anova = rm_anova(scores, scale, within=("strategy",))
        row: dict[str, object] = {
            "scale": scale,
            "items": " / ".join(f"{i}{'ᴿ' if i in REVERSED else ''}. {ITEMS[i - 1]}" for i in items),
            "alpha": cronbach_alpha(scored[[f"q{i}" for i in items]]),
        }
        for s in strategies:
            row[f"mean_{s}"] = float(scores.loc[scores["strategy"] == s, scale].mean())
        if len(anova):
            a = anova.iloc[0]
            row.update(df1=a["df1"], df2=a["df2"], F=a["F"], p=a["p"], partial_eta_sq=a["partial_eta_sq"],
                       estimable=bool(a["estimable"]))  # fmt: skip
        else:
            row.update(df1=np.nan, df2=np.nan, F=np.nan, p=np.nan, partial_eta_sq=np.nan, estimable=False)
        rows.append(row)
    return pd.DataFrame(rows)


def table1_cells(
    table: pd.DataFrame, strategies: Sequence[str] = ("impedance", "learning")
) -> tuple[list[str], list[list[str]]]:
    """Table 1's column titles and formatted cells: scale, questions, α, mean per strategy,
    F(df1, df2), p, partial η²; a test that is not estimable says so instead of F."""
    df = table.dropna(subset=["df2"])
    dfs = f"F({int(df['df1'].iloc[0])},{int(df['df2'].iloc[0])})" if len(df) else "F"
    head = [
        "scale",
        "questions (ᴿ: reverse-scored)",
        "Cronbach's α",
        *(f"{s} mean" for s in strategies),
        dfs,
        "p",
        "partial η²",
    ]
    rows = []
    for _, r in table.iterrows():
        tested = bool(np.isfinite(float(r["df2"])))
        f = markdown.NOT_ESTIMABLE if tested and not bool(r.get("estimable", True)) else _num(r["F"], 2)
        rows.append([
            str(r["scale"]),
            str(r["items"]),
            _num(r["alpha"], 2),
            *(_num(r[f"mean_{s}"], 2) for s in strategies),
            f,
            markdown.p_value(r["p"]),
            _num(r["partial_eta_sq"], 2),
        ])  # fmt: skip
    return head, rows


def table1_markdown(table: pd.DataFrame, strategies: Sequence[str] = ("impedance", "learning")) -> str:
    """Table 1 as Markdown (see :func:`table1_cells`)."""
    return markdown.table(*table1_cells(table, strategies))


def _num(x: object, digits: int) -> str:
    try:
        v = float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return "—"
    return f"{v:.{digits}f}" if np.isfinite(v) else "—"
