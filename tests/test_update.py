"""phri.WeightUpdate / phri.relevance: the cost-form update w ← clip(w − α⊙ΔΦ, lo, hi) against a
numpy reference for every rule (ALL, MAX with range normalisation, confidence scaling), and typed
errors."""

from __future__ import annotations

import re

import numpy as np
import pytest

import phri
from phri import exceptions as ex

RULES = ["all", "max", "confidence"]
TOL = 1e-9


@pytest.fixture
def gen() -> np.random.Generator:
    return np.random.default_rng(20180305)


def reference_update(w, dphi, step, lower, upper, learned, ranges, rule, relevance=None):
    """(new weights, chosen, clipped, max_change) in numpy."""
    w, dphi = np.asarray(w, float), np.asarray(dphi, float)
    moves = np.asarray(learned, bool).copy()
    chosen = None
    if rule == "max":
        if moves.any():
            score = np.where(moves, np.abs(dphi / ranges), -np.inf)
            chosen = int(np.argmax(score))  # first of equal maxima, as the core
        moves = np.zeros_like(moves)
        if chosen is not None:
            moves[chosen] = True
    scale = np.clip(relevance, 0.0, 1.0) if rule == "confidence" else 1.0
    target = w - step * scale * dphi
    new = np.where(moves, np.clip(target, lower, upper), w)
    clipped = bool(np.any(moves & (new != target)))
    max_change = float(np.abs(new - w)[moves].max()) if moves.any() else 0.0
    return new, chosen, clipped, max_change


def random_problem(rng: np.random.Generator, k: int):
    step = rng.uniform(0.0, 5.0, k)
    lower = rng.uniform(-2.0, 1.0, k)
    upper = lower + rng.uniform(0.0, 3.0, k)
    upper[rng.random(k) < 0.2] = np.inf  # unbounded above is allowed
    learned = rng.random(k) < 0.7
    ranges = rng.uniform(0.1, 3.0, k)
    return step, lower, upper, learned, ranges


@pytest.mark.parametrize("rule", RULES)
def test_apply_matches_numpy_reference(gen, rule):
    clipped_seen = 0
    for trial in range(300):
        k = int(gen.integers(1, 7))
        step, lower, upper, learned, ranges = random_problem(gen, k)
        update = phri.WeightUpdate(step, lower, upper, learned=learned, ranges=ranges, rule=rule)
        w = np.clip(gen.uniform(-3.0, 4.0, k), lower, upper)
        dphi = gen.normal(scale=0.5, size=k)
        relevance = gen.uniform(-0.2, 1.2, k)  # the update clamps it into [0, 1]
        new, info = update.apply(w, dphi, relevance if rule == "confidence" else None)
        ref, chosen, clipped, max_change = reference_update(
            w, dphi, step, lower, upper, learned, ranges, rule, relevance
        )
        case = f"trial {trial}: w={w.tolist()} dphi={dphi.tolist()} learned={learned.tolist()}"
        np.testing.assert_allclose(new, ref, rtol=0, atol=TOL, err_msg=case)
        assert info.chosen == chosen, case
        assert info.clipped == clipped, case
        assert abs(info.max_change - max_change) < TOL, case
        assert np.all((new >= lower) & (new <= upper)), case
        clipped_seen += clipped
    assert clipped_seen > 10, "the sweep should exercise the bounds"


def test_the_study_update_in_cost_form():
    # Task 2 (table): weights (efficiency, table), only table learned, gain 2, clip [0, 1].
    update = phri.WeightUpdate([0.0, 2.0], [1.0, 0.0], [1.0, 1.0], learned=[False, True])
    w, info = update.apply([1.0, 0.0], [0.3, -0.2])  # the push lowered the cup: Φ_H − Φ_R < 0
    np.testing.assert_allclose(w, [1.0, 0.4], rtol=0, atol=1e-15)
    assert (info.chosen, info.clipped) == (None, False)
    assert info.max_change == pytest.approx(0.4, abs=1e-15)
    w, info = update.apply(w, [0.0, -1.0])
    np.testing.assert_array_equal(w, [1.0, 1.0])
    assert info.clipped


def test_max_normalises_by_the_ranges_before_choosing():
    dphi = np.array([5.0, 0.5, -0.9])
    ranges = np.array([1.0, 0.6919, 1.8761])
    # Raw |ΔΦ| would pick feature 2 among the learned ones; normalised, 0.5/0.69 > 0.9/1.88.
    update = phri.WeightUpdate(
        [1.0, 1.0, 1.0], [-9.0] * 3, [9.0] * 3, learned=[False, True, True], ranges=ranges
    )
    assert update.rule == "all"
    update = phri.WeightUpdate(
        [1.0, 1.0, 1.0], [-9.0] * 3, [9.0] * 3, learned=[False, True, True], ranges=ranges, rule="max"
    )
    w, info = update.apply(np.zeros(3), dphi)
    assert info.chosen == 1
    np.testing.assert_array_equal(w, [0.0, -0.5, 0.0])
    plain = phri.WeightUpdate([1.0, 1.0, 1.0], [-9.0] * 3, [9.0] * 3, learned=[False, True, True], rule="max")
    assert plain.apply(np.zeros(3), dphi)[1].chosen == 2
    nothing = phri.WeightUpdate([1.0, 1.0], [0.0, 0.0], [1.0, 1.0], learned=[False, False], rule="max")
    w, info = nothing.apply([0.5, 0.5], [1.0, 1.0])
    assert info.chosen is None and info.max_change == 0.0
    np.testing.assert_array_equal(w, [0.5, 0.5])


def test_confidence_scales_each_step_and_requires_relevance():
    update = phri.WeightUpdate([2.0, 100.0], [0.0, 0.0], [1.0, 10.0], rule="confidence")
    w, _ = update.apply([0.5, 5.0], [-0.1, 0.01], relevance=[0.5, 0.0])
    np.testing.assert_allclose(w, [0.6, 5.0], rtol=0, atol=1e-15)
    w, _ = update.apply([0.5, 5.0], [-0.1, 0.01], relevance=[3.0, -1.0])  # clamped to [0, 1]
    np.testing.assert_allclose(w, [0.7, 5.0], rtol=0, atol=1e-15)
    with pytest.raises(ex.InvalidParameterError, match="^relevance is required by the confidence"):
        update.apply([0.5, 5.0], [-0.1, 0.01])


def test_apply_and_clip_return_fresh_arrays():
    update = phri.WeightUpdate([1.0, 1.0], [0.0, 0.0], [1.0, 1.0])
    w = np.array([0.5, 0.5])
    new, _ = update.apply(w, [0.1, -0.1])
    np.testing.assert_array_equal(w, [0.5, 0.5])
    assert new is not w and new.dtype == np.float64
    clipped = update.clip([-3.0, 7.0])
    np.testing.assert_array_equal(clipped, [0.0, 1.0])
    np.testing.assert_array_equal(update.clip(np.array([0.25, 0.75])), [0.25, 0.75])


def test_properties_and_defaults():
    update = phri.WeightUpdate([1.0, 2.0, 3.0], [0.0, 0.0, -np.inf], [1.0, 10.0, np.inf])
    np.testing.assert_array_equal(update.step, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(update.lower, [0.0, 0.0, -np.inf])
    np.testing.assert_array_equal(update.upper, [1.0, 10.0, np.inf])
    np.testing.assert_array_equal(update.learned, [True, True, True])
    assert update.learned.dtype == np.bool_
    np.testing.assert_array_equal(update.ranges, [1.0, 1.0, 1.0])
    assert update.rule == "all" and len(update) == 3
    for rule in RULES:
        assert phri.WeightUpdate([1.0], [0.0], [1.0], rule=rule).rule == rule
    with pytest.raises(AttributeError):
        update.rule = "max"


def test_update_info_is_frozen_and_comparable():
    update = phri.WeightUpdate([1.0, 1.0], [0.0, 0.0], [1.0, 1.0], rule="max")
    _, a = update.apply([0.5, 0.5], [0.1, -0.3])
    _, b = update.apply([0.5, 0.5], [0.1, -0.3])
    assert a == b
    assert (a.chosen, a.clipped) == (1, False) and a.max_change == pytest.approx(0.3)
    assert "UpdateInfo(chosen=1" in repr(a)
    with pytest.raises(AttributeError):
        a.chosen = 0
    with pytest.raises(TypeError):
        phri.UpdateInfo()


# --------------------------------------------------------------------------------------------------
# relevance


def reference_relevance(dphi, sensitivity, u_h):
    push = u_h @ u_h
    s2 = (sensitivity**2).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.minimum(1.0, dphi**2 / (s2 * push))
    return np.where((push > 0) & (s2 > 0), r, 0.0)


def test_relevance_matches_numpy_reference(gen):
    for _ in range(200):
        k, n = int(gen.integers(1, 6)), int(gen.integers(1, 8))
        s = gen.normal(size=(k, n))
        s[gen.random(k) < 0.1] = 0.0
        u = gen.normal(size=n)
        dphi = gen.normal(scale=0.5, size=k)
        np.testing.assert_allclose(
            phri.relevance(dphi, s, u), reference_relevance(dphi, s, u), rtol=0, atol=TOL
        )


def test_relevance_is_one_for_the_cheapest_push_and_zero_without_one():
    s = np.array([[1.0, 2.0, 0.0], [0.0, 0.0, 1.0]])
    u = np.array([0.5, 1.0, 0.0])
    dphi = s @ u  # the change this push produces; row 0 parallel to u, row 1 orthogonal
    np.testing.assert_allclose(phri.relevance(dphi, s, u), [1.0, 0.0], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(phri.relevance(dphi, s, np.zeros(3)), [0.0, 0.0])


def test_relevance_bad_input():
    s, u, d = np.ones((2, 3)), np.ones(3), np.ones(2)
    with pytest.raises(ex.ShapeError, match=re.escape("sensitivity must have shape (2, 3), got (3, 2)")):
        phri.relevance(d, s.T, u)
    with pytest.raises(ex.ShapeError, match=re.escape("u_h must have shape (n,), got (1, 3)")):
        phri.relevance(d, s, u[None])
    with pytest.raises(ex.ShapeError, match=re.escape("delta_phi must have shape (K,), got ()")):
        phri.relevance(1.0, s, u)
    with pytest.raises(ex.NonFiniteError, match="^u_h must be finite"):
        phri.relevance(d, s, [1.0, np.nan, 1.0])
    with pytest.raises(ex.NonFiniteError, match="^sensitivity must be finite"):
        phri.relevance(d, [[1.0, 1.0, 1.0], [1.0, np.inf, 1.0]], u)
    with pytest.raises(ex.NonFiniteError, match="^delta_phi must be finite"):
        phri.relevance([np.nan, 1.0], s, u)


# --------------------------------------------------------------------------------------------------
# errors


def test_unknown_rule_names_the_allowed_values():
    with pytest.raises(
        ex.InvalidParameterError, match=r"^rule must be one of 'all', 'max', 'confidence', 'beta', got 'MAX'"
    ):
        phri.WeightUpdate([1.0], [0.0], [1.0], rule="MAX")


@pytest.mark.parametrize(
    ("kwargs", "error", "pattern"),
    [
        ({"lower": [0.0]}, ex.ShapeError, "lower must have shape (2,) like step, got (1,)"),
        ({"upper": [[1.0, 1.0]]}, ex.ShapeError, "upper must have shape (K,), got (1, 2)"),
        ({"step": [[1.0, 1.0]]}, ex.ShapeError, "step must have shape (K,), got (1, 2)"),
        ({"step": []}, ex.InvalidParameterError, "step must have one entry per feature"),
        ({"step": [1.0, -1.0]}, ex.InvalidParameterError, "step [1] must be >= 0"),
        ({"step": [1.0, np.nan]}, ex.NonFiniteError, "step must be finite"),
        ({"lower": [0.0, 2.0]}, ex.InvalidParameterError, "lower [1] = 2 must not be above upper[1] = 1"),
        ({"lower": [0.0, np.nan]}, ex.InvalidParameterError, "lower [1] = NaN"),
        ({"learned": [True]}, ex.ShapeError, "learned must have shape (2,) like step, got (1,)"),
        ({"ranges": [1.0, 0.0]}, ex.InvalidParameterError, "ranges [1] must be finite and > 0"),
        ({"ranges": [1.0, 1e-320]}, ex.InvalidParameterError, "ranges [1] must be finite and > 0"),
        (
            {"lower": [0.0, np.inf], "upper": [1.0, np.inf]},
            ex.InvalidParameterError,
            "lower [1] = inf and upper[1] = inf leave no finite weight between them",
        ),
        ({"ranges": [1.0]}, ex.ShapeError, "ranges must have shape (2,) like step, got (1,)"),
    ],
)
def test_bad_parameters_are_typed_errors(kwargs, error, pattern):
    args = {"step": [1.0, 1.0], "lower": [0.0, 0.0], "upper": [1.0, 1.0]} | kwargs
    with pytest.raises(error, match="^" + re.escape(pattern)):
        phri.WeightUpdate(**args)


def test_bad_apply_input_is_a_typed_error():
    update = phri.WeightUpdate([1.0, 1.0], [0.0, 0.0], [1.0, 1.0], rule="confidence")
    with pytest.raises(ex.ShapeError, match=re.escape("weights must have shape (2,), got (3,)")):
        update.apply([0.0, 0.0, 0.0], [0.0, 0.0], [1.0, 1.0])
    with pytest.raises(ex.ShapeError, match=re.escape("delta_phi must have shape (2,), got (2, 1)")):
        update.apply([0.0, 0.0], [[0.0], [0.0]], [1.0, 1.0])
    with pytest.raises(ex.ShapeError, match=re.escape("relevance must have shape (2,), got (1,)")):
        update.apply([0.0, 0.0], [0.0, 0.0], [1.0])
    with pytest.raises(ex.NonFiniteError, match=re.escape("delta_phi must be finite, got NaN at index 1")):
        update.apply([0.0, 0.0], [0.0, np.nan], [1.0, 1.0])
    with pytest.raises(ex.NonFiniteError, match="^weights must be finite"):
        update.apply([np.inf, 0.0], [0.0, 0.0], [1.0, 1.0])
    with pytest.raises(ex.NonFiniteError, match="^relevance must be finite"):
        update.apply([0.0, 0.0], [0.0, 0.0], [np.nan, 1.0])
    with pytest.raises(ex.ShapeError, match="^weights must have shape"):
        update.clip([0.0])
    # Finite inputs whose step overflows: an error, and the weights stay as they were.
    unbounded = phri.WeightUpdate([1e308, 1e308], [0.0, -np.inf], [1.0, np.inf])
    weights = np.array([0.5, 0.5])
    with pytest.raises(ex.InvalidParameterError, match=r"^delta_phi \[1\] = -1e9 times step 1e308 overflows"):
        unbounded.apply(weights, [-1e-3, -1e9])
    np.testing.assert_array_equal(weights, [0.5, 0.5])
