"""Cubic splines on the integer steps of a chunk: fitting and fast evaluation.

A chunk's spline has its knots at the steps 0, 1, ..., N-1, so every piece is a cubic in
``u = k - i`` on ``[i, i + 1]``: ``StepSpline`` keeps each piece's four power-form coefficients
and evaluates any number of instants, and their first three derivatives, with a few array
operations. Outside ``[0, N-1]`` the end pieces go on as they are (as scipy's ``BSpline``
extrapolates).

The smoothing spline of ``smoothing_spline`` is the same function as scipy's
``make_smoothing_spline(steps, y, lam=lam)`` (unit weights): the natural cubic spline that
minimises ``sum_k (y_k - f(k))^2 + lam * integral f''(k)^2``. With the knots fixed it is a linear
map of the data that depends only on N and ``lam``, so the map is built once per (N, lam)
(Reinsch's algorithm as in Green & Silverman 1994, chapter 2) and then applied to every joint with one
matrix product.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

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

    coefficients: np.ndarray
    last_step: float
    """The last step the data covered (N - 1): the spline is meant for ``[0, last_step]``."""

    def __call__(self, k: float | np.ndarray, nu: int = 0) -> np.ndarray:
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
            return c[:, 0] + u * (c[:, 1] + u * (c[:, 2] + u * c[:, 3]))
        if nu == 1:
            return c[:, 1] + u * (2.0 * c[:, 2] + u * (3.0 * c[:, 3]))
        if nu == 2:
            return 2.0 * c[:, 2] + u * (6.0 * c[:, 3])
        return 6.0 * c[:, 3]


def smoothing_spline(positions: np.ndarray, lam: float) -> StepSpline:
    """Natural cubic smoothing spline through (N, J) ``positions`` at steps 0..N-1 (N >= 5)."""
    positions = _steps_by_joints(positions)
    n = len(positions)
    if n < MIN_SMOOTHING_STEPS:
        raise ValueError(f"smoothing_spline: needs at least {MIN_SMOOTHING_STEPS} steps, got {n}")
    operator = _smoothing_operator(n, float(lam))
    coefficients = (operator @ positions).reshape(n - 1, 4, -1)
    return StepSpline(coefficients, float(n - 1))


@lru_cache(maxsize=8)  # a run sees one or two (length, weight) pairs; 1.3 MB each at 200 steps
def _smoothing_operator(n: int, lam: float) -> np.ndarray:
    """The (4 (n-1), n) matrix from data to the power-form coefficients of every piece.

    Reinsch's form on unit spacing: ``Q`` (n, n-2) takes second differences (each column holds
    1, -2, 1), ``R`` (n-2, n-2) is tridiagonal (2/3 on the diagonal, 1/6 beside it). The knot
    values ``g`` and the interior second derivatives ``gamma`` (zero at both ends: a natural
    spline) solve ``(R + lam Q^T Q) gamma = Q^T y`` and ``g = y - lam Q gamma``.
    """
    inner = n - 2
    second_difference = np.zeros((inner, n))  # Q^T
    rows = np.arange(inner)
    second_difference[rows, rows] = 1.0
    second_difference[rows, rows + 1] = -2.0
    second_difference[rows, rows + 2] = 1.0
    gamma = np.zeros((n, n))  # row i: the second derivative at step i, per datum
    # R + lam Q^T Q has constant diagonals: Q^T Q is (1, -4, 6, -4, 1) on every row.
    gamma[1:-1] = solve_pentadiagonal(2.0 / 3.0 + 6.0 * lam, 1.0 / 6.0 - 4.0 * lam, lam, second_difference)
    # Q gamma without forming Q: each interior second derivative (rows 1..n-2 of ``gamma``)
    # enters the knot values i, i+1, i+2 with weights 1, -2, 1.
    q_gamma = np.zeros((n, n))
    q_gamma[:inner] += gamma[1:-1]
    q_gamma[1:inner + 1] -= 2.0 * gamma[1:-1]
    q_gamma[2:] += gamma[1:-1]
    values = np.eye(n) - lam * q_gamma
    g0, g1 = values[:-1], values[1:]
    s0, s1 = gamma[:-1], gamma[1:]
    # On [i, i+1]: f = g_i + b u + (s_i / 2) u^2 + ((s_(i+1) - s_i) / 6) u^3, with f(1) = g_(i+1).
    operator = np.stack([g0, g1 - g0 - (2.0 * s0 + s1) / 6.0, 0.5 * s0, (s1 - s0) / 6.0], axis=1)
    operator = operator.reshape(4 * (n - 1), n)
    operator.setflags(write=False)
    return operator


def solve_pentadiagonal(d0: float, d1: float, d2: float, rhs: np.ndarray) -> np.ndarray:
    """``x`` with ``A x = rhs`` for the symmetric positive definite (m, m) matrix ``A`` whose
    diagonal is ``d0`` and whose first and second off-diagonals are ``d1`` and ``d2``.

    LDL^T with two subdiagonals, row by row (no pivoting: ``A`` is positive definite), each row
    of ``rhs`` (m, k) handled at once. Unlike a dense LAPACK solve, it costs O(m k) and starts
    no BLAS threads (a dense 200-step solve took 0.27 s on a loaded 2-core machine).
    """
    m = len(rhs)
    pivot, sub1, sub2 = [1.0, 1.0], [0.0, 0.0], [0.0, 0.0]  # D, L[i, i-1], L[i, i-2]; two unused rows first
    for i in range(m):
        l2 = (d2 if i >= 2 else 0.0) / pivot[-2]
        l1 = ((d1 if i >= 1 else 0.0) - l2 * sub1[-1] * pivot[-2]) / pivot[-1]
        pivot.append(d0 - l1 * l1 * pivot[-1] - l2 * l2 * pivot[-2])
        sub1.append(l1)
        sub2.append(l2)
    pivot, sub1, sub2 = pivot[2:], sub1[2:], sub2[2:]
    x = np.array(rhs, dtype=float)
    for i in range(1, m):  # L z = rhs
        x[i] -= sub1[i] * x[i - 1]
        if i >= 2:
            x[i] -= sub2[i] * x[i - 2]
    x /= np.array(pivot)[:, None]
    for i in range(m - 2, -1, -1):  # L^T x = z / D
        x[i] -= sub1[i + 1] * x[i + 1]
        if i + 2 < m:
            x[i] -= sub2[i + 2] * x[i + 2]
    return x


def interpolating_polynomial(positions: np.ndarray) -> StepSpline:
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


def _steps_by_joints(positions: np.ndarray) -> np.ndarray:
    positions = np.asarray(positions, dtype=float)
    if positions.ndim != 2:
        raise ValueError(f"a chunk's positions must be (steps, joints), got shape {positions.shape}")
    return positions
