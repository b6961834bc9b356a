"""phri's optional dependencies: which extra of the package brings each one, and the one way phri
imports them.

``pip install phri`` installs the core, which needs numpy only (and a TOML reader on Python 3.10).
The rest comes with extras (pyproject.toml's ``[project.optional-dependencies]``):
``phri[sim]`` the simulation and its pictures, ``phri[study]`` the user study and its report (on top
of ``sim``), ``phri[parquet]`` the study's Parquet table, ``phri[ray]`` the Ray backend, ``phri[all]``
everything. A module that is missing is a :class:`~phri.exceptions.MissingExtraError` naming the
``pip install`` that fixes it, never a bare ``ModuleNotFoundError``.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Iterable
from types import ModuleType

from phri.exceptions import MissingExtraError

__all__ = ["EXTRA_OF", "INCLUDES", "NEEDS", "available", "check", "check_part", "require"]

#: The extra that brings each optional top-level module (its distribution has the same name, with
#: "-" for "_").
EXTRA_OF: dict[str, str] = {
    "pybullet": "sim",
    "matplotlib": "sim",
    "pandas": "study",
    "statsmodels": "study",
    "tqdm": "study",
    "scipy": "study",
    "markdown": "view",
    "pyarrow": "parquet",
    "ray": "ray",
    "pylibfranka": "franka",
    "franky_sim": "franka-sim",
}

#: Extras that install other extras: ``phri[study]`` brings ``phri[sim]`` too.
INCLUDES: dict[str, tuple[str, ...]] = {
    "study": ("sim", "view"),
    "franka-sim": ("franka",),
    "all": ("study", "parquet", "ray", "franka-sim"),
}

#: The optional modules each part of phri needs, checked before it starts (:func:`check_part`).
NEEDS: dict[str, tuple[str, ...]] = {
    "the demo": ("pybullet", "matplotlib"),
    "a study": ("pybullet", "pandas", "tqdm"),
    "the report": ("pandas", "statsmodels", "matplotlib", "markdown"),
    "the questionnaire": ("pandas",),
}


def _closure(extra: str) -> set[str]:
    """`extra` and every extra it installs."""
    out = {extra}
    for inner in INCLUDES.get(extra, ()):
        out |= _closure(inner)
    return out


def _top(module: str) -> str:
    top = module.partition(".")[0]
    if top not in EXTRA_OF:
        raise KeyError(f"{module!r} is not one of phri's optional dependencies {sorted(EXTRA_OF)}")
    return top


def _error(missing: Iterable[str], needed_for: str | None) -> MissingExtraError:
    """The error for the top-level modules `missing`, naming the fewest extras that install them."""
    names = list(dict.fromkeys(missing))
    extras = list(dict.fromkeys(EXTRA_OF[m] for m in names))
    extras = [e for e in extras if not any(e in _closure(o) and o != e for o in extras)]
    what = ", ".join(names)
    verb = "is" if len(names) == 1 else "are"
    who = (
        f"{needed_for} needs {what}, which {verb} not installed"
        if needed_for
        else f"{what} {verb} not installed"
    )
    return MissingExtraError(f"{who}: pip install 'phri[{','.join(extras)}]'")


def available(module: str) -> bool:
    """Whether the optional `module` (e.g. "pyarrow") can be imported; does not import it."""
    top = _top(module)
    try:
        return importlib.util.find_spec(top) is not None
    except (ImportError, ValueError):
        return False


def check(modules: Iterable[str], needed_for: str) -> None:
    """Raises one :class:`MissingExtraError` listing every one of the optional `modules` that is not
    installed (`needed_for`, e.g. "phri study", opens the message); imports none of them."""
    missing = [_top(m) for m in modules if not available(m)]
    if missing:
        raise _error(missing, needed_for)


def check_part(part: str) -> None:
    """:func:`check` for the modules that `part` (a key of :data:`NEEDS`, e.g. "the report") needs."""
    check(NEEDS[part], part)


def require(module: str, needed_for: str | None = None) -> ModuleType:
    """The optional `module` (e.g. "pandas" or "statsmodels.formula.api"), imported. If it is not
    installed, a :class:`MissingExtraError` naming the extra that installs it (`needed_for`, e.g. the
    caller's ``__name__``, opens the message); if it is installed but a module it imports is missing,
    one saying so."""
    top = _top(module)
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as e:
        if e.name is not None and e.name.partition(".")[0] != top:  # installed, but broken
            raise MissingExtraError(
                f"{top} is installed but cannot be imported ({e}): pip install --force-reinstall {top}"
            ) from e
        raise _error([top], needed_for) from e
