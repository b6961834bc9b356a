"""A griffe extension for phri's API pages (mkdocs.yml loads it; tests/test_docs.py uses it too).

- The native module's docstrings live in its bindings (crates/phri_py: what ``help()`` shows); its
  stubs (python/phri/_phri.pyi) give the types. Griffe reads the stubs, and this extension fills in
  each class's, function's, method's and property's docstring from the compiled module.
- A constant or field is documented by the ``#:`` comment lines right above it (the Sphinx habit
  phri's sources follow); they become its docstring.
- Sphinx roles in docstrings (:class:`~phri.x.Y`, :func:`f`, ``code``) become Markdown code.
"""

from __future__ import annotations

import importlib
import inspect
import re
from typing import Any

import griffe

#: Sphinx roles, e.g. :class:`~phri.sim.World` or :data:`STUDY_TASKS`; shown as the last name.
_ROLE = re.compile(r":(?:class|func|meth|data|attr|mod|exc|obj|const):`~?(?:[\w.]*\.)?([\w]+)`")
#: reST's inline literal ``x``; Markdown shows `x` the same.
_LITERAL = re.compile(r"``([^`]+)``")
#: A wrapped line that starts with ">" (as in "> 0"): text, not a Markdown quote.
_QUOTE = re.compile(r"^(\s*)>", re.M)


def markdown(text: str) -> str:
    """A docstring with its Sphinx roles and reST literals as Markdown code, and a line that
    happens to start with ">" kept as text."""
    return _QUOTE.sub(r"\1\\>", _LITERAL.sub(r"`\1`", _ROLE.sub(r"`\1`", text)))


def comment_docstring(attr: griffe.Attribute) -> str | None:
    """The ``#:`` comment lines right above `attr`'s definition, joined (None if there are none)."""
    if attr.lineno is None or attr.filepath is None or isinstance(attr.filepath, list):
        return None
    lines = attr.lines_collection[attr.filepath] if attr.filepath in attr.lines_collection else []
    found: list[str] = []
    k = attr.lineno - 2
    while 0 <= k < len(lines) and lines[k].strip().startswith("#:"):
        found.insert(0, lines[k].strip()[2:].strip())
        k -= 1
    return " ".join(found) or None


class PhriDocstrings(griffe.Extension):
    """Docstrings of the native module from the compiled module, of constants from ``#:`` comments,
    and Markdown for Sphinx roles."""

    def on_attribute_instance(self, *, attr: griffe.Attribute, **kwargs: Any) -> None:
        """Gives an attribute documented by ``#:`` comments its docstring."""
        if attr.docstring is None:
            text = comment_docstring(attr)
            if text:
                attr.docstring = griffe.Docstring(text, parent=attr)

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        """Fills the native module's docstrings from the compiled module, then rewrites the roles."""
        if pkg.name != "phri":
            return
        native = importlib.import_module("phri._phri")
        for obj in _walk(pkg["_phri"]):
            runtime: Any = native
            try:
                for part in obj.path.split(".")[2:]:
                    runtime = getattr(runtime, part)
            except AttributeError:
                continue
            if not (obj.is_class or obj.is_function or "property" in obj.labels):
                continue  # a constant's docstring would be its type's: it keeps its ``#:`` comment
            doc = getattr(runtime, "__doc__", None)
            if doc and doc.strip():
                obj.docstring = griffe.Docstring(inspect.cleandoc(doc), parent=obj)
        for obj in _walk(pkg):
            if obj.docstring is not None:
                obj.docstring.value = markdown(obj.docstring.value)


def _walk(obj: griffe.Object) -> list[griffe.Object]:
    """`obj` and every object defined in it (aliases left out)."""
    out = [obj]
    for member in obj.members.values():
        if not member.is_alias:
            out.extend(_walk(member))  # type: ignore[arg-type]
    return out
