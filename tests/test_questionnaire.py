"""The Table 1 questionnaire: items, reverse scoring, Cronbach's α, the CSV, asking on the terminal,
the per-scale repeated-measures ANOVA and the Table 1 output."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from phri.exceptions import ConfigError
from phri.study import StudyConfig, run_study
from phri.study import questionnaire as q
from phri.study.cli import main as cli
from phri.study.errors import QuestionnaireError

HEADER = "participant,strategy," + ",".join(f"q{i}" for i in range(1, 11))
#: A study of four participants (no episodes are run: the questionnaire only needs its folder).
FOUR = StudyConfig(participants=4, tasks=("human", "laptop"), duration=8.0, waypoints=7)


def study_folder(path: Path, config: StudyConfig = FOUR) -> Path:
    run_study(path, config, backend="serial", progress=False, max_episodes=0)
    return path


def write_csv(path: Path, rows: list[str]) -> Path:
    path.write_text("\n".join([HEADER, *rows]) + "\n")
    return path


def synthetic(n: int = 10, seed: int = 0) -> pd.DataFrame:
    """Answers of `n` participants who like learning better (raw, before reverse scoring)."""
    rng = np.random.default_rng(seed)
    rows = []
    for p in range(1, n + 1):
        for s, base in (("impedance", 2), ("learning", 5)):
            answers = {}
            for i in range(1, 11):
                x = base if i not in q.REVERSED else 8 - base
                answers[f"q{i}"] = int(np.clip(x + rng.integers(-1, 2), 1, 7))
            rows.append({"participant": p, "strategy": s, **answers})
    return pd.DataFrame(rows)


def test_items_and_scales_are_the_papers() -> None:
    assert len(q.ITEMS) == 10
    assert q.ITEMS[0].startswith("By the end, the robot understood")
    assert q.ITEMS[9] == "The robot did not collaborate with me to complete the task."
    assert q.REVERSED == (2, 4, 5, 8, 10)
    assert q.SCALES == {
        "understanding": (1, 2, 3, 4),
        "effort": (5, 6),
        "predictability": (7, 8),
        "collaboration": (9, 10),
    }
    assert sorted(i for items in q.SCALES.values() for i in items) == list(range(1, 11))


def test_reverse_scoring() -> None:
    raw = pd.DataFrame(
        [{"participant": 1, "strategy": "learning", **{f"q{i}": i % 7 + 1 for i in range(1, 11)}}]
    )
    scored = q.reverse_score(raw)
    for i in range(1, 11):
        expected = 8 - raw[f"q{i}"][0] if i in (2, 4, 5, 8, 10) else raw[f"q{i}"][0]
        assert scored[f"q{i}"][0] == expected, i
    assert raw["q2"][0] == 3  # the input is not modified
    # All 7s: the positive items stay 7, the negative ones become 1.
    sevens = pd.DataFrame([{"participant": 1, "strategy": "learning", **{f"q{i}": 7 for i in range(1, 11)}}])
    scores = q.scale_scores(sevens).iloc[0]
    assert scores["understanding"] == 4.0 and scores["effort"] == 4.0
    assert scores["predictability"] == 4.0 and scores["collaboration"] == 4.0


def test_cronbach_alpha_known_example() -> None:
    # 5 respondents × 3 items: item variances 2.5, 1.3, 4.3; total-score variance 22.5 →
    # α = 3/2 · (1 − 8.1/22.5) = 0.96 exactly.
    x = np.array([[3, 4, 3], [5, 5, 6], [2, 3, 2], [6, 6, 7], [4, 5, 4]], dtype=float)
    assert x.var(axis=0, ddof=1).tolist() == pytest.approx([2.5, 1.3, 4.3])
    assert x.sum(axis=1).var(ddof=1) == pytest.approx(22.5)
    assert q.cronbach_alpha(x) == pytest.approx(0.96, rel=1e-12)
    # Identical items: α = 1. Uncorrelated items: α near 0 (here negative).
    assert q.cronbach_alpha(np.repeat(np.arange(6.0)[:, None], 3, axis=1)) == pytest.approx(1.0)
    assert q.cronbach_alpha(np.array([[1, 3], [2, 1], [3, 2]], dtype=float)) < 0.2
    # Undefined cases.
    assert np.isnan(q.cronbach_alpha(np.ones((4, 3))))
    assert np.isnan(q.cronbach_alpha(x[:, :1]))
    assert np.isnan(q.cronbach_alpha(x[:1]))


def test_cronbach_alpha_matches_the_variance_formula_on_random_data() -> None:
    rng = np.random.default_rng(5)
    for _ in range(20):
        n, k = int(rng.integers(3, 15)), int(rng.integers(2, 6))
        x = rng.integers(1, 8, (n, k)).astype(float)
        if x.sum(axis=1).var() == 0:
            continue
        formula = k / (k - 1) * (1 - x.var(axis=0, ddof=1).sum() / x.sum(axis=1).var(ddof=1))
        assert q.cronbach_alpha(x) == pytest.approx(formula, rel=1e-9, abs=1e-12), x


def test_csv_import(tmp_path: Path) -> None:
    path = write_csv(
        tmp_path / "a.csv", ["1,impedance,1,7,2,6,7,1,3,5,2,6", "1,learning,6,2,7,1,2,6,5,3,6,2"]
    )
    responses = q.read_responses(path)
    assert list(responses.columns) == ["participant", "strategy", *(f"q{i}" for i in range(1, 11))]
    assert responses["q2"].tolist() == [7, 2] and responses["q2"].dtype == np.int64
    scores = q.scale_scores(responses)
    assert scores.loc[0, "understanding"] == pytest.approx((1 + 1 + 2 + 2) / 4)
    assert scores.loc[1, "understanding"] == pytest.approx((6 + 6 + 7 + 7) / 4)
    assert scores.loc[0, "effort"] == pytest.approx((1 + 1) / 2)
    # Extra columns are ignored; column order does not matter.
    shuffled = tmp_path / "b.csv"
    backwards = range(10, 0, -1)
    shuffled.write_text(
        "note,strategy,participant," + ",".join(f"q{i}" for i in backwards) + "\n"
        "x,learning,3," + ",".join(str(i % 7 + 1) for i in backwards) + "\n"
    )
    assert q.read_responses(shuffled).loc[0, "q10"] == 10 % 7 + 1


@pytest.mark.parametrize(
    ("rows", "match"),
    [
        (["1,impedance,1,7,2,6,8,1,3,5,2,6"], r"line 2: column 'q5' must be 1-7"),
        (["1,impedance,1,7,2,6,0,1,3,5,2,6"], r"line 2: column 'q5' must be 1-7"),
        (["1,impedance,1,7,2,6,x,1,3,5,2,6"], r"line 2: column 'q5' must be a whole number"),
        (["1,impedance,1,7,2,6,4.5,1,3,5,2,6"], r"column 'q5' must be a whole number"),
        (["1,impedance,1,7,2,6,7,1,3,5,2"], r"line 2: column 'q10' is missing"),
        (["1,,1,7,2,6,7,1,3,5,2,6"], r"column 'strategy' is missing"),
        (
            ["1,impedance,1,7,2,6,7,1,3,5,2,6", "1,impedance,1,7,2,6,7,1,3,5,2,6"],
            r"line 3: participant 1 answered twice",
        ),
        (["0,impedance,1,7,2,6,7,1,3,5,2,6"], r"line 2: column 'participant' must be >= 1"),
        # Blank lines are skipped, and the line named is the file's.
        (["1,impedance,1,7,2,6,7,1,3,5,2,6", "", "2,impedance,1,7,2,6,9,1,3,5,2,6"], r"line 4: column 'q5'"),
        ([], "no responses"),
    ],
)
def test_bad_csv_is_a_clear_error(tmp_path: Path, rows: list[str], match: str) -> None:
    path = write_csv(tmp_path / "bad.csv", rows)
    with pytest.raises(QuestionnaireError, match=match) as info:
        q.read_responses(path)
    assert str(path) in str(info.value) and isinstance(info.value, ConfigError)


def test_missing_columns_and_files(tmp_path: Path) -> None:
    path = tmp_path / "cols.csv"
    path.write_text("participant,strategy,q1\n1,learning,3\n")
    with pytest.raises(QuestionnaireError, match=r"missing column\(s\) \['q2'"):
        q.read_responses(path)
    with pytest.raises(QuestionnaireError, match="cannot read"):
        q.read_responses(tmp_path / "none.csv")


def test_ask_on_the_terminal(tmp_path: Path) -> None:
    typed = iter(["4", "8", "seven", "", "7", "1", "2", "3", "4", "5", "6", "7", "1"])
    shown: list[str] = []
    answers = q.ask(
        3, "learning", read=lambda prompt: (shown.append(prompt), next(typed))[1], write=shown.append
    )
    assert answers == {
        "q1": 4,
        "q2": 7,
        "q3": 1,
        "q4": 2,
        "q5": 3,
        "q6": 4,
        "q7": 5,
        "q8": 6,
        "q9": 7,
        "q10": 1,
    }
    assert sum("please type a whole number from 1 to 7" in s for s in shown) == 3
    assert any(q.ITEMS[9] in s for s in shown)

    def ends(prompt: str) -> str:
        raise EOFError

    with pytest.raises(QuestionnaireError, match="input ended at item 1"):
        q.ask(1, "impedance", read=ends, write=lambda s: None)
    # Appending: a header once, one row per questionnaire, no second answer for the same pair.
    path = tmp_path / "answers.csv"
    q.append_response(path, 3, "learning", answers)
    q.append_response(path, 3, "impedance", {**answers, "q1": 1})
    assert path.read_text().count("participant") == 1
    assert q.read_responses(path)["q1"].tolist() == [4, 1]
    before = path.read_bytes()
    with pytest.raises(QuestionnaireError, match="already answered"):
        q.append_response(path, 3, "learning", answers)
    with pytest.raises(QuestionnaireError, match="must be 1-7"):
        q.append_response(path, 4, "learning", {**answers, "q3": 9})
    assert path.read_bytes() == before


def test_table1_matches_paired_t_tests() -> None:
    responses = synthetic()
    table = q.table1(responses)
    assert table["scale"].tolist() == list(q.SCALES)
    scores = q.scale_scores(responses)
    scored = q.reverse_score(responses)
    for _, row in table.iterrows():
        s = row["scale"]
        wide = scores.pivot(index="participant", columns="strategy", values=s)
        t = stats.ttest_rel(wide["learning"], wide["impedance"])
        assert (row["df1"], row["df2"]) == (1, 9)  # the paper's F(1, 9)
        assert row["F"] == pytest.approx(t.statistic**2, rel=1e-9)
        assert row["p"] == pytest.approx(t.pvalue, rel=1e-6)
        assert row["mean_learning"] == pytest.approx(wide["learning"].mean())
        assert row["mean_impedance"] == pytest.approx(wide["impedance"].mean())
        assert row["alpha"] == pytest.approx(q.cronbach_alpha(scored[[f"q{i}" for i in q.SCALES[s]]]))
        assert row["mean_learning"] > row["mean_impedance"]
    text = q.table1_markdown(table)
    assert "F(1,9)" in text and "< .0001" in text and "2ᴿ. Even by the end" in text
    assert text.count("\n") == 2 + 4
    with pytest.raises(QuestionnaireError, match="telepathy"):
        q.table1(responses.assign(strategy="telepathy"))


def test_table1_without_error_variance_is_not_estimable() -> None:
    """Every participant rates learning the same amount above impedance: the ANOVA's error term has no
    variance, and Table 1 says "not estimable" instead of an F."""
    answers = synthetic(4)
    learning = answers["strategy"] == "learning"
    answers.loc[learning, "q1"] = 6
    answers.loc[~learning, "q1"] = 3
    for i in (2, 3, 4):  # the understanding scale: the same for everyone, per strategy
        answers[f"q{i}"] = answers["q1"] if i not in q.REVERSED else 8 - answers["q1"]
    t1 = q.table1(answers).set_index("scale")
    assert not t1.loc["understanding", "estimable"] and np.isnan(t1.loc["understanding", "F"])
    assert t1.drop(index="understanding")["estimable"].all()
    text = q.table1_markdown(t1.reset_index())
    row = next(line for line in text.splitlines() if line.startswith("| understanding"))
    assert "| not estimable | — | — |" in row


def test_cli_import_and_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run_dir = study_folder(tmp_path / "study")
    source = tmp_path / "answers.csv"
    synthetic(4).to_csv(source, index=False)
    assert cli(["questionnaire", str(run_dir), "--import", str(source)]) == 0
    assert "8 questionnaire(s) added" in capsys.readouterr().out
    # Importing again adds nothing; conflicting answers are refused and change nothing.
    assert cli(["questionnaire", str(run_dir), "--import", str(source)]) == 0
    assert "0 questionnaire(s) added" in capsys.readouterr().out
    before = (run_dir / "questionnaire.csv").read_bytes()
    conflicting = synthetic(4).assign(q1=1)
    conflicting.to_csv(source, index=False)
    assert cli(["questionnaire", str(run_dir), "--import", str(source)]) == 2
    assert "differs from the answers already" in capsys.readouterr().err
    assert (run_dir / "questionnaire.csv").read_bytes() == before
    assert cli(["questionnaire", str(tmp_path / "nowhere"), "--import", str(source)]) == 2
    # A folder without a study: nothing to check the answers against.
    (tmp_path / "bare").mkdir()
    assert cli(["questionnaire", str(tmp_path / "bare"), "--import", str(source)]) == 2
    assert "no study.json" in capsys.readouterr().err
    assert not (tmp_path / "bare" / "questionnaire.csv").exists()


@pytest.mark.parametrize(
    ("row", "match"),
    [
        ("5,learning,1,7,2,6,7,1,3,5,2,6",
         r"line 4: column 'participant' must be one of the study's participants 1-4, got 5"),
        ("2,learnin,1,7,2,6,7,1,3,5,2,6",
         r"line 4: column 'strategy' must be one of the study's strategies \['impedance', 'learning'\], "
         r"got 'learnin'"),
    ],
)  # fmt: skip
def test_import_checks_the_study_and_is_all_or_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], row: str, match: str
) -> None:
    """One row for a participant or strategy the study does not have: an error naming the line and
    the column, and none of the valid rows before it is added."""
    run_dir = study_folder(tmp_path / "study")
    target = run_dir / "questionnaire.csv"
    source = write_csv(
        tmp_path / "a.csv", ["1,impedance,1,7,2,6,7,1,3,5,2,6", "1,learning,6,2,7,1,2,6,5,3,6,2", row]
    )
    with pytest.raises(QuestionnaireError, match=match) as info:
        q.import_responses(source, target, study=FOUR)
    assert str(source) in str(info.value)
    assert not target.exists()
    # With answers already there: the file is unchanged.
    q.append_response(target, 3, "learning", {f"q{i}": 4 for i in range(1, 11)}, study=FOUR)
    before = target.read_bytes()
    assert cli(["questionnaire", str(run_dir), "--import", str(source)]) == 2
    assert "line 4" in capsys.readouterr().err
    assert target.read_bytes() == before
    assert not list(run_dir.glob("*.partial"))
    # The same rows without the bad one go in, all at once, after the existing answer.
    write_csv(source, ["1,impedance,1,7,2,6,7,1,3,5,2,6", "1,learning,6,2,7,1,2,6,5,3,6,2"])
    assert q.import_responses(source, target, study=FOUR) == 2
    assert q.read_responses(target)[["participant", "strategy"]].values.tolist() == [
        [3, "learning"], [1, "impedance"], [1, "learning"],
    ]  # fmt: skip


def test_terminal_entry_checks_the_study_before_asking(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    run_dir = study_folder(tmp_path / "study")

    def ask(participant: int, strategy: str) -> dict[str, int]:
        raise AssertionError("asked although the participant or strategy is not the study's")

    monkeypatch.setattr(q, "ask", ask)
    assert cli(["questionnaire", str(run_dir), "--participant", "9", "--strategy", "learning"]) == 2
    err = capsys.readouterr().err
    assert "questionnaire: --participant must be one of the study's participants 1-4, got 9" in err
    assert cli(["questionnaire", str(run_dir), "--participant", "2", "--strategy", "telepathy"]) == 2
    assert "--strategy must be one of the study's strategies" in capsys.readouterr().err
    assert not (run_dir / "questionnaire.csv").exists()
    monkeypatch.setattr(q, "ask", lambda p, s: {f"q{i}": 5 for i in range(1, 11)})
    assert cli(["questionnaire", str(run_dir), "--participant", "2", "--strategy", "learning"]) == 0
    assert q.read_responses(run_dir / "questionnaire.csv")["participant"].tolist() == [2]
    with pytest.raises(QuestionnaireError, match="participants 1-4, got 5"):
        q.append_response(
            run_dir / "questionnaire.csv", 5, "learning", {f"q{i}": 5 for i in range(1, 11)}, study=FOUR
        )


def test_append_after_a_file_without_final_newline(tmp_path: Path) -> None:
    """A file saved by an editor without its last newline: the next answer starts a new line."""
    path = tmp_path / "answers.csv"
    path.write_text(HEADER + "\n1,impedance,1,7,2,6,7,1,3,5,2,6")
    q.append_response(path, 1, "learning", {f"q{i}": 3 for i in range(1, 11)})
    assert q.read_responses(path)[["participant", "strategy", "q1"]].values.tolist() == [
        [1, "impedance", 1], [1, "learning", 3],
    ]  # fmt: skip


def _import_one(args: tuple[str, str]) -> int:
    return q.import_responses(args[0], args[1])


def test_concurrent_imports_lose_no_answer(tmp_path: Path) -> None:
    """Issue 16 #1: imports in 12 processes at once, each adding its own participant's answers, all
    land (each read-check-write of the target holds its lock) and the header survives."""
    import multiprocessing

    sources = []
    for p in range(1, 13):
        row = f"{p},learning," + ",".join(str(1 + (p + i) % 7) for i in range(10))
        sources.append((str(write_csv(tmp_path / f"in{p}.csv", [row])), str(tmp_path / "answers.csv")))
    with multiprocessing.get_context("fork").Pool(6) as pool:
        added = pool.map(_import_one, sources)
    assert added == [1] * 12
    table = q.read_responses(tmp_path / "answers.csv")
    assert sorted(table["participant"]) == list(range(1, 13))
    assert (tmp_path / "answers.csv").read_text().startswith(HEADER + "\n")


def test_excel_and_latin1_files(tmp_path: Path) -> None:
    """Issue 16 #11, #21: Excel's CSV UTF-8 (a byte-order mark, CRLF) is read; a Latin-1 file is a
    QuestionnaireError naming the line, not a UnicodeDecodeError."""
    rows = [HEADER, "1,learning" + ",4" * 10]
    excel = tmp_path / "excel.csv"
    excel.write_bytes(b"\xef\xbb\xbf" + "\r\n".join(rows).encode() + b"\r\n")
    assert list(q.read_responses(excel)["participant"]) == [1]
    latin = tmp_path / "latin.csv"
    latin.write_bytes("\n".join([HEADER + ",note", "1,learning" + ",4" * 10 + ",caf\xe9"]).encode("latin-1"))
    with pytest.raises(QuestionnaireError, match=r"latin.csv: line 2: byte b'\\xe9' is not UTF-8"):
        q.read_responses(latin)
