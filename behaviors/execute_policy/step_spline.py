"""The chunk's fit: cubic splines on the integer steps of a chunk, fitted and evaluated fast.

``fit_chunk`` smooths a chunk with a cubic smoothing spline (fixed smoothing, weighted by
``policy_tracking_weight``; no per-chunk cross-validation, which costs ~90 ms); a chunk too short
for one is interpolated exactly.

A chunk's spline has its knots at the steps 0, 1, ..., N-1, so every piece is a cubic in
``u = k - i`` on ``[i, i + 1]``: ``StepSpline`` keeps each piece's four power-form coefficients
and evaluates any number of instants, and their first three derivatives, with a few array
operations. Outside ``[0, N-1]`` the end pieces go on as they are (as scipy's ``BSpline``
extrapolates).

The smoothing spline of ``smoothing_spline`` is the same function as scipy's
``make_smoothing_spline(steps, y, lam=lam)`` (unit weights): the natural cubic spline that
minimises ``sum_k (y_k - f(k))^2 + lam * integral f''(k)^2``, found by Reinsch's algorithm (Green &
Silverman 1994, chapter 2). Its one linear system is pentadiagonal, solved in time and memory
linear in the chunk's steps; a chunk of up to ``DENSE_MAP_MAX_STEPS`` steps is smoothed through
that solve's linear maps, kept per length and weight.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

MIN_SMOOTHING_STEPS = 5
"""Fewest steps a smoothing spline is fitted to (as scipy's ``make_smoothing_spline``)."""


_DERIVATIVE_FACTORS = ((1.0, 1.0, 1.0, 1.0), (1.0, 2.0, 3.0), (2.0, 6.0), (6.0,))
"""The nu-th derivative of ``sum_d c_d u^d`` is ``sum_d factor_d c_(d+nu) u^d``."""


@dataclass(frozen=True)
class StepSpline:
    """A piecewise cubic with pieces on ``[i, i + 1]``, i = 0 .. P-1.

    ``coefficients`` is (P, 4, J): piece i is ``c0 + c1 u + c2 u^2 + c3 u^3`` with ``u = k - i``,
    per joint. Before 0 the first piece extends, after P the last one; a single piece is a
    polynomial everywhere.
    """

    coefficients: NDArray[np.float64]
    last_step: float
    """The last step the data covered (N - 1): the spline is meant for ``[0, last_step]``."""

    def __call__(self, k: float | NDArray[np.float64], nu: int = 0) -> NDArray[np.float64]:
        """The ``nu``-th derivative (0 to 3, per step) at step(s) ``k``: (J,) for a scalar
        ``k``, (M, J) for M steps."""
        if nu not in (0, 1, 2, 3):
            raise ValueError(f"StepSpline: derivative order nu={nu} is not one of 0, 1, 2, 3")
        last_piece = len(self.coefficients) - 1
        if np.ndim(k) == 0:  # one instant: plain floats are several times cheaper than arrays
            step = float(k)
            piece = min(max(math.floor(step), 0), last_piece)
            u = step - piece
            weights = [f * u**d for d, f in enumerate(_DERIVATIVE_FACTORS[nu])]
            return np.array(weights) @ self.coefficients[piece, nu:]
        steps = np.asarray(k, dtype=float)
        if steps.shape == (1,):
            return self(steps[0], nu)[None, :]
        piece = np.minimum(np.floor(np.maximum(steps, 0.0)), last_piece)
        u = (steps - piece)[:, None]
        c = self.coefficients.take(piece.astype(np.intp), axis=0)  # (M, 4, J)
        if nu == 0:
            values: NDArray[np.float64] = c[:, 0] + u * (c[:, 1] + u * (c[:, 2] + u * c[:, 3]))
        elif nu == 1:
            values = c[:, 1] + u * (2.0 * c[:, 2] + u * (3.0 * c[:, 3]))
        elif nu == 2:
            values = 2.0 * c[:, 2] + u * (6.0 * c[:, 3])
        else:
            values = 6.0 * c[:, 3]
        return values


def smoothing_spline(positions: NDArray[np.float64], lam: float) -> StepSpline:
    """Natural cubic smoothing spline through (N, J) ``positions`` at steps 0..N-1 (N >= 5).

    Reinsch's form on unit spacing: ``Q`` (N, N-2) takes second differences (each column holds
    1, -2, 1), ``R`` (N-2, N-2) is tridiagonal (2/3 on the diagonal, 1/6 beside it). The interior
    second derivatives ``gamma`` (zero at both ends: a natural spline) solve the pentadiagonal
    ``(R + lam Q^T Q) gamma = Q^T y``, and the knot values are ``g = y - lam Q gamma``.
    """
    y = _steps_by_joints(positions)
    n = len(y)
    if n < MIN_SMOOTHING_STEPS:
        raise ValueError(f"smoothing_spline: needs at least {MIN_SMOOTHING_STEPS} steps, got {n}")
    if n <= DENSE_MAP_MAX_STEPS:
        return StepSpline((_smoothing_operator(n, float(lam)) @ y).reshape(n - 1, 4, -1), float(n - 1))
    return StepSpline(_power_form(*_reinsch(y, float(lam))), float(n - 1))


DENSE_MAP_MAX_STEPS = 256
"""Chunks of up to this many steps are smoothed through one (4 (N-1), N) map kept per length and
weight (``_smoothing_operator``: one small matrix product, at most 2 MB); longer ones by the banded
solve itself, whose time and memory are linear in the steps."""


def _power_form(g: NDArray[np.float64], gamma: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N-1, 4, ...) power-form coefficients of the pieces of the cubic with knot values ``g`` and
    second derivatives ``gamma`` (N, ...)."""
    g0, g1, s0, s1 = g[:-1], g[1:], gamma[:-1], gamma[1:]
    # On [i, i+1]: f = g_i + b u + (s_i / 2) u^2 + ((s_(i+1) - s_i) / 6) u^3, with f(1) = g_(i+1).
    return np.stack([g0, g1 - g0 - (2.0 * s0 + s1) / 6.0, 0.5 * s0, (s1 - s0) / 6.0], axis=1)


def _reinsch(y: NDArray[np.float64], lam: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The knot values ``g`` and second derivatives ``gamma`` (both (N, J)) of the smoothing
    spline of (N, J) ``y``: one banded solve."""
    gamma = np.zeros_like(y)  # row i: the second derivative at step i
    # R + lam Q^T Q has constant diagonals: Q^T Q is (1, -4, 6, -4, 1) on every row.
    gamma[1:-1] = solve_pentadiagonal(2.0 / 3.0 + 6.0 * lam, 1.0 / 6.0 - 4.0 * lam, lam, y[:-2] - 2.0 * y[1:-1] + y[2:])
    # Q gamma: each interior second derivative enters the knot values i-1, i, i+1 with weights 1, -2, 1.
    q_gamma = np.zeros_like(y)
    q_gamma[:-2] += gamma[1:-1]
    q_gamma[1:-1] -= 2.0 * gamma[1:-1]
    q_gamma[2:] += gamma[1:-1]
    return y - lam * q_gamma, gamma


@functools.lru_cache(maxsize=8)
def _smoothing_operator(n: int, lam: float) -> NDArray[np.float64]:
    """The (4 (N-1), N) linear map from a chunk's values to its smoothing spline's power-form
    coefficients (``_reinsch`` of the identity), read-only: the smoothing is linear in the
    values, and ExecutePolicy fits chunks of one length with one weight run after run."""
    operator = _power_form(*_reinsch(np.eye(n), lam)).reshape(4 * (n - 1), n)
    operator.setflags(write=False)
    return operator


def solve_pentadiagonal(d0: float, d1: float, d2: float, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
    """``x`` with ``A x = rhs`` for the symmetric positive definite (m, m) matrix ``A`` whose
    diagonal is ``d0`` and whose first and second off-diagonals are ``d1`` and ``d2``.

    LAPACK's banded Cholesky (``scipy.linalg.solveh_banded``): time and memory O(m k) for an
    (m, k) ``rhs``, and no BLAS threads (a dense 200-step solve took 0.27 s on a loaded 2-core
    machine; a Python loop over the rows, 1 ms at 50 steps). ``ExecutePolicy`` imports scipy.linalg
    in its setup, so the first chunk does not pay for it.
    """
    from scipy.linalg import solveh_banded

    rhs = np.asarray(rhs, dtype=float)
    bands = np.empty((3, len(rhs)))  # upper form: row 2 the diagonal, rows 1 and 0 the two above it
    bands[0], bands[1], bands[2] = d2, d1, d0
    return solveh_banded(bands, rhs, check_finite=False)


def interpolating_polynomial(positions: NDArray[np.float64]) -> StepSpline:
    """The polynomial of degree N-1 through (N, J) ``positions`` at steps 0..N-1, for 1 <= N <= 4
    (what scipy's ``make_interp_spline`` gives for so few points); one step is held constant
    over ``[0, 1]``."""
    positions = _steps_by_joints(positions)
    n = len(positions)
    if not 1 <= n < MIN_SMOOTHING_STEPS:
        raise ValueError(f"interpolating_polynomial: needs 1 to {MIN_SMOOTHING_STEPS - 1} steps, got {n}")
    coefficients = np.zeros((1, 4, positions.shape[1]))
    coefficients[0, :n] = np.linalg.solve(np.vander(np.arange(n, dtype=float), n, increasing=True), positions)
    return StepSpline(coefficients, float(max(n - 1, 1)))


def _steps_by_joints(positions: NDArray[np.float64]) -> NDArray[np.float64]:
    positions = np.asarray(positions, dtype=float)
    if positions.ndim != 2:
        raise ValueError(f"a chunk's positions must be (steps, joints), got shape {positions.shape}")
    return positions


def fit_chunk(positions: NDArray[np.float64], tracking_weight: float) -> StepSpline:
    """Smoothing spline through a (N, J) chunk, parameterised by step index.

    The spline minimises ``w * sum((y_k - f(k))^2) + integral(f''(k)^2)`` with
    ``w = tracking_weight``; counting time in steps makes the weight mean the same at any dt.
    It equals scipy's ``make_smoothing_spline(steps, positions, lam=1 / w)``. Chunks too short
    for a smoothing spline (fewer than 5 steps) are interpolated exactly.
    """
    positions = np.asarray(positions, dtype=float)
    if len(positions) >= MIN_SMOOTHING_STEPS:
        return smoothing_spline(positions, 1.0 / tracking_weight)
    return interpolating_polynomial(positions)
