"""The seam blend (behaviors/execute_policy/seam.py), ExecutePolicy's and the simulated trajectory
controllers': its shape, its peaks and its length."""
import numpy as np
import pytest

from behaviors.execute_policy.seam import (
    POSITION_BLEND_PEAK,
    VELOCITY_BLEND_PEAK,
    acceleration_basis,
    blend_duration,
    blend_offset,
    position_basis,
    velocity_basis,
)
from sim.controllers.trajectory import quintic_coefficients, quintic_powers

TAU = np.linspace(0.0, 1.0, 20001)


def test_each_basis_starts_at_its_unit_state_and_ends_at_rest():
    for basis, start in ((position_basis, (1, 0, 0)), (velocity_basis, (0, 1, 0)), (acceleration_basis, (0, 0, 1))):
        value, slope, curve = basis(np.array([0.0, 1.0]))
        assert (value[0], slope[0], curve[0]) == start
        assert (value[1], slope[1], curve[1]) == (0, 0, 0)


def test_the_peaks_are_the_largest_curvatures_of_the_position_and_velocity_bases():
    assert np.abs(position_basis(TAU)[2]).max() == pytest.approx(POSITION_BLEND_PEAK, rel=1e-6)
    assert np.abs(velocity_basis(TAU)[2]).max() == pytest.approx(VELOCITY_BLEND_PEAK, rel=1e-6)
    assert np.abs(acceleration_basis(TAU)[2]).max() == 1.0  # at the seam


def test_the_blend_is_the_quintic_the_controllers_interpolate_with():
    d, w, c, T = np.array([0.3, -0.1]), np.array([0.5, 2.0]), np.array([-4.0, 1.0]), 0.7
    zeros = np.zeros((1, 2))
    coefficients = quintic_coefficients(np.array([T]), d[None], w[None], c[None], zeros, zeros, zeros)[0]
    t = np.linspace(0.0, T, 9)
    p, v, a = blend_offset(d, w, c, T, t)
    expected = np.array([quintic_powers(x) @ coefficients for x in t])
    np.testing.assert_allclose(np.stack([p, v, a], axis=1), expected, atol=1e-12)
    after = blend_offset(d, w, c, T, np.array([T, T + 1.0]))
    assert all(np.all(x == 0.0) for x in after)


def test_blend_duration_is_the_nominal_one_unless_the_offset_needs_longer():
    budget = np.array([2.5, 2.5])
    assert blend_duration(np.array([0.001, 0.0]), np.zeros(2), budget, 1.0) == 1.0
    # A position offset d over T adds at most d * 10/sqrt(3) / T^2, a velocity offset w at most w * 3.94 / T.
    assert blend_duration(np.array([1.0, 0.0]), np.zeros(2), budget, 0.5) == pytest.approx(np.sqrt(POSITION_BLEND_PEAK / 2.5))
    assert blend_duration(np.zeros(2), np.array([0.0, 2.0]), budget, 0.5) == pytest.approx(2.0 * VELOCITY_BLEND_PEAK / 2.5)
    # No budget on a joint (the chunk alone is at its limit): it does not lengthen the blend.
    assert blend_duration(np.array([1.0, 0.0]), np.zeros(2), np.array([0.0, 2.5]), 0.5) == 0.5


@pytest.mark.parametrize("d, w", [(0.003, 0.05), (1.0, 0.0), (0.0, 2.0), (-0.4, 1.5), (0.02, -0.3)])
def test_a_blend_of_that_duration_stays_within_the_budget(d, w):
    budget = 1.7
    T = blend_duration(np.array([d]), np.array([w]), budget, 0.01)
    _, _, a = blend_offset(np.array([d]), np.array([w]), np.zeros(1), T, TAU * T)
    assert np.abs(a).max() <= budget * (1 + 1e-9)
