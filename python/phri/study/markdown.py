"""How the study's reports write tables and numbers in Markdown: one table writer and one p-value
format for the report's statistics and the questionnaire's Table 1."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

__all__ = ["NOT_ESTIMABLE", "number", "p_value", "table"]

#: What a report writes for a test that is not estimable (its error term without variance, see
#: :mod:`phri.study.analysis`) in place of F, p and the effect size.
NOT_ESTIMABLE = "not estimable"


def number(x: object, digits: int = 3) -> str:
    """`x` with `digits` decimals (scientific notation when it is that small or 1e5 or more); "—" for
    NaN or infinity; a value that is not a number as it is."""
    try:
        v = float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return str(x)
    if not np.isfinite(v):
        return "—"
    if v != 0 and (abs(v) >= 1e5 or abs(v) < 10**-(digits)):
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}f}"


def p_value(p: object) -> str:
    """A p-value with four decimals, "< .0001" below that (the paper's threshold), "—" if undefined."""
    v = float(p)  # type: ignore[arg-type]
    return "—" if not np.isfinite(v) else ("< .0001" if v < 1e-4 else f"{v:.4f}")


def table(head: Sequence[str], rows: Iterable[Sequence[object]]) -> str:
    """A Markdown table with the column titles `head` and the cells of `rows` (a "|" in a cell is
    escaped)."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for cells in rows:
        lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines) + "\n"
