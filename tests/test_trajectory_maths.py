"""The fast paths of the trajectory maths equal the textbook formulas they replaced.

The control loop samples its trajectory 500 times a second and every goal builds hundreds of
quintic pieces, so ``quintic_coefficients`` works on all pieces at once and ``Trajectory.sample``
evaluates position, velocity and acceleration with one small matmul. These tests pin them to the
one-piece-at-a-time formula and to Horner evaluation on random data.
"""
from __future__ import annotations

import numpy as np
import pytest

from sim.controllers.trajectory import Trajectory, quintic_coefficients, quintic_powers


def one_piece(h, p0, v0, a0, p1, v1, a1):
    """The quintic Hermite coefficients of a single piece (6 x J), written out."""
    dp = p1 - p0
    c3 = (20 * dp - (8 * v1 + 12 * v0) * h - (3 * a0 - a1) * h**2) / (2 * h**3)
    c4 = (-30 * dp + (14 * v1 + 16 * v0) * h + (3 * a0 - 2 * a1) * h**2) / (2 * h**4)
    c5 = (12 * dp - 6 * (v1 + v0) * h + (a1 - a0) * h**2) / (2 * h**5)
    return np.stack([p0, v0, a0 / 2.0, c3, c4, c5])


def horner(c, tau):
    """Position, velocity and acceleration of sum c_k tau^k by Horner's rule."""
    position = c[0] + tau * (c[1] + tau * (c[2] + tau * (c[3] + tau * (c[4] + tau * c[5]))))
    velocity = c[1] + tau * (2 * c[2] + tau * (3 * c[3] + tau * (4 * c[4] + tau * 5 * c[5])))
    acceleration = 2 * c[2] + tau * (6 * c[3] + tau * (12 * c[4] + tau * 20 * c[5]))
    return position, velocity, acceleration


def random_trajectory(rng: np.random.Generator, points: int = 200, joints: int = 6) -> Trajectory:
    times = 3.0 + np.cumsum(rng.uniform(0.002, 0.05, points))
    shape = (points, joints)
    return Trajectory(times, rng.normal(size=shape), rng.normal(size=shape), rng.normal(scale=5.0, size=shape))


@pytest.mark.parametrize("seed", range(5))
def test_vectorised_coefficients_equal_the_one_piece_formula(seed):
    rng = np.random.default_rng(seed)
    tr = random_trajectory(rng)
    p, v, a, h = tr.positions, tr.velocities, tr.accelerations, np.diff(tr.times)
    expected = np.stack([one_piece(h[k], p[k], v[k], a[k], p[k + 1], v[k + 1], a[k + 1]) for k in range(h.size)])
    got = quintic_coefficients(h, p[:-1], v[:-1], a[:-1], p[1:], v[1:], a[1:])
    assert got.shape == (199, 6, 6)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0)


@pytest.mark.parametrize("seed", range(5))
def test_sample_equals_horner_evaluation_of_the_piece(seed):
    rng = np.random.default_rng(seed)
    tr = random_trajectory(rng)
    h = np.diff(tr.times)
    for t in rng.uniform(tr.start_time, tr.end_time, 300):
        k = int(np.searchsorted(tr.times, t, side="right")) - 1
        c = one_piece(h[k], tr.positions[k], tr.velocities[k], tr.accelerations[k], tr.positions[k + 1], tr.velocities[k + 1], tr.accelerations[k + 1])
        expected = horner(c, t - tr.times[k])
        state = tr.sample(t)
        for got, want in zip((state.position, state.velocity, state.acceleration), expected):
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


def test_sample_hits_knots_exactly_and_holds_outside():
    tr = random_trajectory(np.random.default_rng(7), points=20)
    for k in (0, 7, 19):
        state = tr.sample(float(tr.times[k]))
        np.testing.assert_array_equal(state.position, tr.positions[k])
        np.testing.assert_allclose(state.velocity, tr.velocities[k], rtol=1e-12, atol=1e-12)
    before, after = tr.sample(tr.start_time - 1.0), tr.sample(tr.end_time + 1.0)
    np.testing.assert_array_equal(before.position, tr.positions[0])
    np.testing.assert_array_equal(after.position, tr.positions[-1])
    assert not before.velocity.any() and not after.acceleration.any()


def test_quintic_powers_are_the_monomials_and_their_derivatives():
    tau = 0.3
    np.testing.assert_allclose(
        quintic_powers(tau),
        [
            [1, tau, tau**2, tau**3, tau**4, tau**5],
            [0, 1, 2 * tau, 3 * tau**2, 4 * tau**3, 5 * tau**4],
            [0, 0, 2, 6 * tau, 12 * tau**2, 20 * tau**3],
        ],
        rtol=1e-15,
    )


def test_a_single_point_trajectory_is_a_hold():
    tr = Trajectory.hold(2.0, np.array([0.1, -0.2]))
    assert tr.start_time == tr.end_time == 2.0
    np.testing.assert_array_equal(tr.sample(2.5).position, [0.1, -0.2])
    assert tr.trimmed_before(5.0) is tr
