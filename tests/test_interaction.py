"""phri.InteractionDetector: per-joint thresholding against a numpy reference, defaults, typed errors."""

from __future__ import annotations

import re

import numpy as np
import pytest

import phri
from phri import exceptions as ex

JACO2_THRESHOLDS = [8.0, 8.0, 8.0, 2.0, 1.0, 1.0, 1.0]  # N·m, the authors' published code


@pytest.fixture
def gen() -> np.random.Generator:
    return np.random.default_rng(1010)


def reference_detect(tau, thresholds, bias):
    v = np.asarray(tau, float) - bias
    over = np.abs(v) > thresholds
    return bool(over.any()), np.where(over, v, 0.0)


def test_defaults_are_the_original_jaco2_thresholds():
    d = phri.InteractionDetector()
    np.testing.assert_array_equal(d.thresholds, JACO2_THRESHOLDS)
    np.testing.assert_array_equal(d.bias, np.zeros(7))
    assert d.thresholds.dtype == np.float64


def test_detect_matches_numpy_reference(gen):
    later = np.array([4.0, 5.0, 3.0, 4.0, 1.5, 1.5, 1.5])  # the later versions' thresholds
    for thresholds, bias in [
        (np.array(JACO2_THRESHOLDS), np.zeros(7)),
        (later, gen.normal(scale=0.3, size=7)),
        (gen.uniform(0.5, 3.0, 3), gen.normal(scale=0.3, size=3)),
    ]:
        d = phri.InteractionDetector(thresholds, bias)
        hits = 0
        for _ in range(500):
            tau = gen.normal(scale=0.5 * thresholds + 0.1)
            any_, u_h = d.detect(tau)
            ref_any, ref_u = reference_detect(tau, thresholds, bias)
            assert any_ == ref_any, tau
            np.testing.assert_allclose(u_h, ref_u, rtol=0, atol=1e-12, err_msg=str(tau.tolist()))
            hits += any_
        assert 20 < hits < 480, hits


def test_thresholds_are_strict_and_small_components_are_zeroed():
    d = phri.InteractionDetector()
    any_, u_h = d.detect([8.0, -8.0, 7.9, 2.0, -1.0, 1.0, 0.5])  # exactly at threshold: no
    assert not any_
    np.testing.assert_array_equal(u_h, np.zeros(7))
    any_, u_h = d.detect((9.0, 1.0, 0.0, -2.5, 0.0, 0.0, 0.0))
    assert any_ is True
    np.testing.assert_array_equal(u_h, [9.0, 0.0, 0.0, -2.5, 0.0, 0.0, 0.0])


def test_bias_is_removed_before_thresholding():
    d = phri.InteractionDetector(bias=[0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(d.bias, [0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0])
    assert not d.detect([0.0, 0.0, 0.0, 4.5, 0.0, 0.0, 0.0])[0]
    any_, u_h = d.detect([0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    assert any_
    np.testing.assert_array_equal(u_h, [0.0, 0.0, 0.0, -2.5, 0.0, 0.0, 0.0])


def test_properties_are_copies():
    d = phri.InteractionDetector()
    t = d.thresholds
    t[:] = 0.0
    np.testing.assert_array_equal(d.thresholds, JACO2_THRESHOLDS)


@pytest.mark.parametrize(
    ("kwargs", "error", "pattern"),
    [
        ({"thresholds": [1.0, -1.0]}, ex.InvalidParameterError, "thresholds [1] must be >= 0 N·m, got -1"),
        ({"thresholds": [1.0, np.nan]}, ex.NonFiniteError, "thresholds must be finite, got NaN at index 1"),
        ({"thresholds": []}, ex.InvalidParameterError, "thresholds must have one entry per joint"),
        ({"thresholds": [[1.0, 2.0]]}, ex.ShapeError, "thresholds must have shape (n,), got (1, 2)"),
        ({"bias": np.zeros(6)}, ex.ShapeError, "bias must have shape (7,), got (6,)"),
        ({"bias": [0.0, 0.0, 0.0, np.inf, 0.0, 0.0, 0.0]}, ex.NonFiniteError, "bias must be finite"),
    ],
)
def test_bad_parameters_are_typed_errors(kwargs, error, pattern):
    with pytest.raises(error, match="^" + re.escape(pattern)):
        phri.InteractionDetector(**kwargs)


def test_bad_measurements_are_typed_errors():
    d = phri.InteractionDetector()
    with pytest.raises(ex.ShapeError, match=re.escape("tau_measured must have shape (7,), got (6,)")):
        d.detect(np.zeros(6))
    with pytest.raises(ex.ShapeError, match=re.escape("tau_measured must have shape (7,), got (1, 7)")):
        d.detect(np.zeros((1, 7)))
    with pytest.raises(ex.NonFiniteError, match=re.escape("tau_measured must be finite, got NaN at index 2")):
        d.detect([0.0, 0.0, np.nan, 0.0, 0.0, 0.0, 0.0])
