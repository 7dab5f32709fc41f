"""ExecutePolicy's chunk spline is scipy's smoothing spline, evaluated without scipy.

``fit_chunk`` solves the smoothing spline's banded system for the chunk (time and memory linear
in its steps) and evaluates it piece by piece; scipy's ``make_smoothing_spline`` (and ``make_interp_spline`` for chunks of fewer
than 5 steps, what ``fit_chunk`` used before) is the reference: same values and derivatives,
inside the chunk and beyond both ends.
"""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import make_interp_spline, make_smoothing_spline

from behaviors.execute_policy.step_spline import DENSE_MAP_MAX_STEPS, StepSpline, fit_chunk, interpolating_polynomial, smoothing_spline, solve_pentadiagonal

TOLERANCE = 1e-9


def _chunk(seed: int, steps: int, joints: int, scale: float) -> np.ndarray:
    """A random walk per joint, offset and scaled: what a policy's noisy chunk looks like."""
    rng = np.random.default_rng(seed)
    walk = np.cumsum(rng.normal(0.0, 0.05, size=(steps, joints)), axis=0)
    return scale * (walk + rng.uniform(-3.0, 3.0, size=joints))


def _assert_same_function(reference, spline: StepSpline, steps: int) -> None:
    """Values and first three derivatives agree, from one step before the chunk to one after,
    for arrays of steps, single steps and one-step arrays."""
    k = np.concatenate([np.linspace(-1.0, steps, 5 * steps + 3), np.arange(steps, dtype=float)])
    for nu in range(4):
        expected = reference(k, nu=nu)
        scale = max(1.0, float(np.max(np.abs(expected))))
        assert np.max(np.abs(spline(k, nu) - expected)) <= TOLERANCE * scale, f"derivative {nu}"
        for i in (0, 1, len(k) // 2, len(k) - 1):
            assert np.max(np.abs(spline(float(k[i]), nu) - expected[i])) <= TOLERANCE * scale, f"derivative {nu} at {k[i]}"
            assert np.max(np.abs(spline(k[i:i + 1], nu) - expected[i:i + 1])) <= TOLERANCE * scale


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    steps=st.integers(5, 200),
    joints=st.integers(1, 7),
    tracking_weight=st.floats(1e-3, 1e6),
    scale=st.sampled_from([1e-3, 1.0, 10.0]),
)
def test_fit_chunk_equals_scipy_make_smoothing_spline(seed, steps, joints, tracking_weight, scale):
    chunk = _chunk(seed, steps, joints, scale)
    reference = make_smoothing_spline(np.arange(steps, dtype=float), chunk, lam=1.0 / tracking_weight, axis=0)
    spline = fit_chunk(chunk, tracking_weight)
    _assert_same_function(reference, spline, steps)
    assert spline.last_step == reference.t[-1] == steps - 1


@pytest.mark.parametrize("steps", [DENSE_MAP_MAX_STEPS, DENSE_MAP_MAX_STEPS + 1, 3000])
def test_a_long_chunk_is_still_scipy_s_smoothing_spline(steps):
    """Either side of the length where the kept linear maps give way to the banded solve."""
    chunk = _chunk(9, steps, 7, 1.0)
    reference = make_smoothing_spline(np.arange(steps, dtype=float), chunk, lam=1.0 / 300.0, axis=0)
    _assert_same_function(reference, fit_chunk(chunk, 300.0), steps)


@pytest.mark.parametrize("steps", [1, 2, 3, 4])
def test_short_chunks_are_interpolated_as_make_interp_spline_did(steps):
    chunk = _chunk(steps, steps, 3, 1.0)
    knots, rows, degree = np.arange(steps, dtype=float), chunk, min(3, steps - 1)
    if degree == 0:  # one step: held over [0, 1]
        knots, rows, degree = np.array([0.0, 1.0]), np.vstack([chunk, chunk]), 1
    reference = make_interp_spline(knots, rows, k=degree, axis=0)
    spline = fit_chunk(chunk, 300.0)
    _assert_same_function(reference, spline, steps)
    assert np.allclose(spline(np.arange(steps, dtype=float)), chunk, atol=1e-12)
    assert spline.last_step == reference.t[-1]


@pytest.mark.parametrize("size", [1, 2, 3, 8, 60])
def test_pentadiagonal_solve_matches_the_dense_matrix(size):
    d0, d1, d2 = 0.7, 0.1, 0.02  # R + lam Q^T Q for lam = 0.02 would be 0.787, 0.087, 0.02
    dense = sum(np.diag(np.full(size - abs(k), v), k) for k, v in ((0, d0), (1, d1), (-1, d1), (2, d2), (-2, d2)) if size > abs(k))
    rhs = np.random.default_rng(size).normal(size=(size, 3))
    assert np.allclose(dense @ solve_pentadiagonal(d0, d1, d2, rhs), rhs, atol=1e-12)


def test_each_chunk_gets_its_own_fit():
    a, b = _chunk(1, 50, 6, 1.0), _chunk(2, 50, 6, 1.0)
    fit_a, fit_b = smoothing_spline(a, 1.0 / 300.0), smoothing_spline(b, 1.0 / 300.0)
    k = np.arange(50.0)
    assert np.max(np.abs(fit_a(k) - a)) < 0.05 and np.max(np.abs(fit_b(k) - b)) < 0.05
    assert not np.allclose(fit_a(k), fit_b(k))


def test_scalar_step_gives_one_row_and_arrays_give_one_row_per_step():
    spline = fit_chunk(_chunk(3, 20, 6, 1.0), 300.0)
    assert spline(3.0).shape == (6,)
    assert spline(np.array([3.0]), nu=1).shape == (1, 6)
    assert spline(np.linspace(0, 19, 7), nu=2).shape == (7, 6)


def test_bad_requests_say_what_is_wrong():
    spline = fit_chunk(_chunk(4, 20, 2, 1.0), 300.0)
    with pytest.raises(ValueError, match="derivative order nu=4 is not one of 0, 1, 2, 3"):
        spline(1.0, nu=4)
    with pytest.raises(ValueError, match="needs at least 5 steps, got 4"):
        smoothing_spline(np.zeros((4, 2)), 1.0)
    with pytest.raises(ValueError, match="needs 1 to 4 steps, got 0"):
        interpolating_polynomial(np.zeros((0, 2)))
    with pytest.raises(ValueError, match=r"must be \(steps, joints\), got shape \(20,\)"):
        fit_chunk(np.zeros(20), 300.0)


def _fit_peak_bytes(steps: int) -> int:
    chunk = _chunk(5, steps, 7, 1.0)
    fit_chunk(chunk[:10], 300.0)  # the solver's imports are not the fit's memory
    tracemalloc.start()
    try:
        spline = fit_chunk(chunk, 300.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.max(np.abs(spline(np.arange(float(steps))) - chunk)) < 0.05
    return peak


def test_a_long_chunk_is_fitted_in_memory_linear_in_its_steps():
    """A 2,000-step chunk fits in under 2 MB (a few copies of its 112 kB of values; the dense
    n x n map took 320 MB and was cached), and 10,000 steps (``MAX_CHUNK_STEPS``) take about
    five times as much, not 25 times."""
    from behaviors.execute_policy.chunk import MAX_CHUNK_STEPS

    peak_2000 = _fit_peak_bytes(2000)
    assert peak_2000 < 2_000_000
    assert _fit_peak_bytes(MAX_CHUNK_STEPS) < 6 * peak_2000
