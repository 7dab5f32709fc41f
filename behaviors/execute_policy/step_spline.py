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
(Reinsch's form, Green & Silverman 1994, section 2.3) and then applied to every joint with one
matrix product.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

MIN_SMOOTHING_STEPS = 5
"""Fewest steps a smoothing spline is fitted to (as scipy's ``make_smoothing_spline``)."""


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
        ``k``, else (M, J)."""
        if nu not in (0, 1, 2, 3):
            raise ValueError(f"StepSpline: derivative order nu={nu} is not one of 0, 1, 2, 3")
        k_array = np.asarray(k, dtype=float)
        steps = k_array.reshape(-1)
        piece = np.minimum(np.floor(np.maximum(steps, 0.0)), len(self.coefficients) - 1)
        u = (steps - piece)[:, None]
        c = self.coefficients.take(piece.astype(np.intp), axis=0)  # (M, 4, J)
        if nu == 0:
            out = c[:, 0] + u * (c[:, 1] + u * (c[:, 2] + u * c[:, 3]))
        elif nu == 1:
            out = c[:, 1] + u * (2.0 * c[:, 2] + u * (3.0 * c[:, 3]))
        elif nu == 2:
            out = 2.0 * c[:, 2] + u * (6.0 * c[:, 3])
        else:
            out = 6.0 * c[:, 3]
        return out[0] if k_array.ndim == 0 else out


def smoothing_spline(positions: np.ndarray, lam: float) -> StepSpline:
    """Natural cubic smoothing spline through (N, J) ``positions`` at steps 0..N-1 (N >= 5)."""
    positions = np.asarray(positions, dtype=float)
    n = len(positions)
    if n < MIN_SMOOTHING_STEPS:
        raise ValueError(f"smoothing_spline: needs at least {MIN_SMOOTHING_STEPS} steps, got {n}")
    operator = _smoothing_operator(n, float(lam))
    coefficients = (operator @ positions.reshape(n, -1)).reshape(n - 1, 4, -1)
    return StepSpline(coefficients, float(n - 1))


@lru_cache(maxsize=16)
def _smoothing_operator(n: int, lam: float) -> np.ndarray:
    """The (4 (n-1), n) matrix from data to the power-form coefficients of every piece.

    Reinsch's form on unit spacing: ``Q`` (n, n-2) holds the second differences, ``R`` (n-2, n-2)
    is tridiagonal (2/3 on the diagonal, 1/6 beside it). The knot values ``g`` and the interior
    second derivatives ``gamma`` (zero at both ends: a natural spline) solve
    ``(R + lam Q^T Q) gamma = Q^T y`` and ``g = y - lam Q gamma``.
    """
    inner = n - 2
    q = np.zeros((n, inner))
    columns = np.arange(inner)
    q[columns, columns] = 1.0
    q[columns + 1, columns] = -2.0
    q[columns + 2, columns] = 1.0
    r = np.diag(np.full(inner, 2.0 / 3.0)) + np.diag(np.full(inner - 1, 1.0 / 6.0), 1) + np.diag(np.full(inner - 1, 1.0 / 6.0), -1)
    gamma_inner = np.linalg.solve(r + lam * (q.T @ q), q.T)  # (n-2, n)
    values = np.eye(n) - lam * (q @ gamma_inner)  # (n, n)
    gamma = np.vstack([np.zeros((1, n)), gamma_inner, np.zeros((1, n))])
    g0, g1 = values[:-1], values[1:]
    s0, s1 = gamma[:-1], gamma[1:]
    # On [i, i+1]: f = g_i + b u + (s_i / 2) u^2 + ((s_{i+1} - s_i) / 6) u^3, f(1) = g_{i+1}.
    operator = np.stack([g0, g1 - g0 - (2.0 * s0 + s1) / 6.0, 0.5 * s0, (s1 - s0) / 6.0], axis=1)
    operator = operator.reshape(4 * (n - 1), n)
    operator.setflags(write=False)
    return operator


def interpolating_polynomial(positions: np.ndarray) -> StepSpline:
    """The polynomial of degree N-1 through (N, J) ``positions`` at steps 0..N-1, for 1 <= N <= 4
    (what scipy's ``make_interp_spline`` gives for so few points); one step is held constant
    over ``[0, 1]``."""
    positions = np.asarray(positions, dtype=float)
    n = len(positions)
    if not 1 <= n < MIN_SMOOTHING_STEPS:
        raise ValueError(f"interpolating_polynomial: needs 1 to {MIN_SMOOTHING_STEPS - 1} steps, got {n}")
    flat = positions.reshape(n, -1)
    coefficients = np.zeros((1, 4, flat.shape[1]))
    coefficients[0, :n] = np.linalg.solve(np.vander(np.arange(n, dtype=float), n, increasing=True), flat)
    return StepSpline(coefficients, float(max(n - 1, 1)))
