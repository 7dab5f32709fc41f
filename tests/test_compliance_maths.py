"""The admittance maths on its fast paths equals the plain formulas (random data)."""
from __future__ import annotations

import numpy as np
import pytest

from sim.controllers.compliance import (
    AdmittanceParams,
    AdmittanceState,
    admittance_step,
    damped_pseudo_inverse,
)


@pytest.mark.parametrize("seed", range(5))
def test_damped_pseudo_inverse_is_jt_times_the_damped_inverse(seed):
    rng = np.random.default_rng(seed)
    jacobian = rng.normal(size=(6, 6))
    expected = jacobian.T @ np.linalg.inv(jacobian @ jacobian.T + 1e-6 * np.eye(6))
    np.testing.assert_allclose(damped_pseudo_inverse(jacobian), expected, rtol=1e-10, atol=1e-12)
    cartesian = rng.normal(size=(6, 2))
    reference = jacobian.T @ np.linalg.solve(jacobian @ jacobian.T + 1e-6 * np.eye(6), cartesian)
    np.testing.assert_allclose(damped_pseudo_inverse(jacobian) @ cartesian, reference, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(damped_pseudo_inverse(jacobian) @ cartesian[:, 0], reference[:, 0], rtol=1e-10, atol=1e-12)


def test_damped_pseudo_inverse_stays_bounded_at_a_singularity():
    jacobian = np.eye(6)
    jacobian[5, 5] = 0.0  # the arm cannot rotate about z here
    inverse = damped_pseudo_inverse(jacobian)
    np.testing.assert_allclose(inverse[:5, :5], np.eye(5), atol=1e-5)
    assert inverse[5, 5] == 0.0


def test_a_non_finite_jacobian_is_refused_or_propagates_nan():
    jacobian = np.eye(6)
    jacobian[0, 0] = np.nan
    try:
        result = damped_pseudo_inverse(jacobian)
    except np.linalg.LinAlgError as err:
        assert "is the Jacobian finite?" in str(err)
    else:
        assert np.isnan(result).any()


def numpy_admittance_step(state: AdmittanceState, wrench: np.ndarray, params: AdmittanceParams, dt: float) -> AdmittanceState:
    """The same step written with numpy on all six axes at once."""
    force = np.sign(wrench) * np.maximum(np.abs(wrench) - params.deadband, 0.0)
    rate = state.rate + (force - params.damping * state.rate - params.stiffness * state.offset) / params.mass * dt
    offset = state.offset + rate * dt
    clipped = np.clip(offset, -params.max_offset, params.max_offset)
    return AdmittanceState(clipped, np.where(clipped != offset, 0.0, rate))


@pytest.mark.parametrize("seed", range(5))
def test_admittance_step_matches_semi_implicit_euler_with_deadband_and_clipping(seed):
    rng = np.random.default_rng(seed)
    params = AdmittanceParams().with_goal(rng.uniform(10.0, 3000.0, 6), [])
    state = AdmittanceState(rng.uniform(-0.12, 0.12, 6), rng.normal(size=6))
    for _ in range(200):
        # Components inside the deadband, exactly zero, and beyond it.
        wrench = rng.normal(scale=rng.choice([0.05, 30.0]), size=6) * rng.integers(0, 2, size=6)
        step = admittance_step(state, wrench, params, 0.002)
        expected = numpy_admittance_step(state, wrench, params, 0.002)
        np.testing.assert_array_equal(step.offset, expected.offset)
        np.testing.assert_array_equal(step.rate, expected.rate)
        state = step
    assert np.abs(state.offset).max() <= params.max_offset.max()


def test_a_push_beyond_the_deadband_yields_and_springs_back():
    params, state = AdmittanceParams(), AdmittanceState()
    push = np.array([0.0, 0.0, -21.0, 0.0, 0.0, 0.0])  # 20 N beyond the 1 N deadband
    for _ in range(1000):
        state = admittance_step(state, push, params, 0.002)
    assert state.offset[2] == pytest.approx(-0.01, abs=1e-4)  # 20 N / 2000 N/m
    assert not state.offset[[0, 1, 3, 4, 5]].any()
    for _ in range(1000):
        state = admittance_step(state, np.zeros(6), params, 0.002)
    assert abs(state.offset[2]) < 1e-5


def test_a_released_push_comes_to_exact_rest_and_a_wrench_inside_the_deadband_keeps_it_there():
    params, state = AdmittanceParams(), AdmittanceState()
    assert state.at_rest
    push = np.array([0.0, 0.0, -21.0, 0.0, 0.0, 0.0])
    for _ in range(100):
        state = admittance_step(state, push, params, 0.002)
    assert not state.at_rest and state.offset[2] < -0.009
    released_steps = 0
    while not state.at_rest and released_steps < 5000:
        state = admittance_step(state, np.zeros(6), params, 0.002)
        released_steps += 1
    # Critically damped at 20 rad/s: below REST_EPS about 1.6 s after the release, then exact zeros.
    assert 1.4 <= released_steps * 0.002 <= 1.8
    assert not state.offset.any() and not state.rate.any()
    inside = np.array([0.9, -1.0, 0.5, 0.09, 0.0, -0.1])  # |each axis| <= its deadband
    assert admittance_step(state, inside, params, 0.002) is state
    outside = inside + np.array([0.0, -0.01, 0.0, 0.0, 0.0, 0.0])
    assert not admittance_step(state, outside, params, 0.002).at_rest
