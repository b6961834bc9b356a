"""How the study's reports write tables in LaTeX: the cells of the Markdown tables (same numbers, same
"not estimable"), as a ``tabular`` with booktabs rules, for ``\\input`` into a paper.

Needs ``\\usepackage{booktabs}`` in the document; the text is ASCII (the report's symbols — ±, −, η²,
·, ‖, subscripts — become LaTeX commands), so it compiles with pdfLaTeX as well as LuaLaTeX.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

__all__ = ["escape", "table"]

#: LaTeX's special characters in text.
_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "<": r"\textless{}",
    ">": r"\textgreater{}",
    "|": r"\textbar{}",
}
#: The symbols the report's tables use, as LaTeX.
_SYMBOLS = {
    "±": r"$\pm$",
    "−": r"$-$",
    "·": r"$\cdot$",
    "×": r"$\times$",
    "η": r"$\eta$",
    "α": r"$\alpha$",
    "Σ": r"$\Sigma$",
    "²": r"\textsuperscript{2}",
    "₁": r"\textsubscript{1}",
    "ᴿ": r"\textsuperscript{R}",
    "‖": r"$\|$",
    "≤": r"$\leq$",
    "≥": r"$\geq$",
    "—": "---",
    "–": "--",
    "’": "'",
    "“": "``",
    "”": "''",
}


def escape(text: object) -> str:
    """`text` as LaTeX text: its special characters escaped, the report's symbols as commands; any
    other character outside ASCII is kept (it needs a Unicode engine or a package)."""
    return "".join(_SPECIAL.get(c) or _SYMBOLS.get(c) or c for c in str(text))


def table(head: Sequence[str], rows: Iterable[Sequence[object]]) -> str:
    """A booktabs ``tabular`` with the column titles `head` and the cells of `rows`, every cell
    escaped; every column left-aligned (cells mix numbers and text)."""
    lines = [
        r"\begin{tabular}{" + "l" * len(head) + "}",
        r"\toprule",
        " & ".join(escape(h) for h in head) + r" \\",
        r"\midrule",
    ]
    lines += [" & ".join(escape(c) for c in cells) + r" \\" for cells in rows]
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines) + "\n"
