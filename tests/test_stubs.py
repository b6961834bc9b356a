"""The stubs' `Literal` names are the core's: each list of names is defined once, in Rust, and exported."""

from __future__ import annotations

import ast
from importlib import resources

import pytest

from phri import _phri

# Stub alias → the native module's constant that defines its names.
ALIASES = {"_FeatureName": "FEATURE_NAMES", "_UpdateRule": "UPDATE_RULES"}


def stub_literals() -> dict[str, tuple[str, ...]]:
    """Every `_Name = Literal["a", "b", ...]` alias in the shipped stub file."""
    tree = ast.parse(resources.files("phri").joinpath("_phri.pyi").read_text(encoding="utf-8"))
    found = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Subscript):
            (target,) = node.targets
            if isinstance(target, ast.Name) and getattr(node.value.value, "id", None) == "Literal":
                names = node.value.slice
                items = names.elts if isinstance(names, ast.Tuple) else [names]
                found[target.id] = tuple(ast.literal_eval(item) for item in items)
    return found


@pytest.mark.parametrize(("alias", "constant"), sorted(ALIASES.items()))
def test_stub_literal_matches_the_core(alias, constant):
    literals = stub_literals()
    assert alias in literals, f"the stub has no {alias} = Literal[...]"
    runtime = getattr(_phri, constant)
    assert isinstance(runtime, tuple)
    assert literals[alias] == runtime


def test_the_core_names_are_the_papers():
    assert _phri.FEATURE_NAMES == ("efficiency", "table", "coffee", "coffee_dot", "laptop", "human", "origin")
    assert _phri.UPDATE_RULES == ("all", "max", "confidence", "beta")
