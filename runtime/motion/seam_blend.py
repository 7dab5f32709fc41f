"""The seam blend: how one motion takes over from another without a jump.

At a seam the new motion differs from the one it replaces by an offset in position ``d``,
velocity ``w`` and acceleration ``c`` (per joint). The blend adds to the new motion the quintic
``d h0(tau) + w T h1(tau) + c T^2 h2(tau)``, ``tau = (t - seam) / T``: it equals the offset at the
seam and fades to zero, with its slope and curvature, ``T`` seconds later. ``h0`` and ``h1`` have
zero curvature at the seam, so a position and a velocity offset add no acceleration step there.

``blend_duration`` is how long ``T`` must be for the position and velocity parts to add no more
than an acceleration budget per joint (a closed form of the quintic's peaks); the acceleration
part adds at most ``|c|`` (at the seam) and fades with the rest.

Used by ExecutePolicy, which blends each chunk into the motion already sent
(``behaviors/execute_policy/seam.py``, evaluated in ``shaping.ChunkMotion``), and by the simulated trajectory controllers, which
blend a new goal into the one they play (``sim/controllers/trajectory.py``).
"""
from __future__ import annotations

import math

import numpy as np

Basis = tuple[np.ndarray, np.ndarray, np.ndarray]
"""A basis function's value, slope and curvature with respect to ``tau``."""


def position_basis(tau: np.ndarray) -> Basis:
    """``h0``: value 1 at 0; zero slope and curvature at 0; zero value, slope and curvature at 1."""
    t2, t3 = tau * tau, tau * tau * tau
    value = 1 - 10 * t3 + 15 * t3 * tau - 6 * t3 * t2
    slope = -30 * t2 + 60 * t3 - 30 * t3 * tau
    curve = -60 * tau + 180 * t2 - 120 * t3
    return value, slope, curve


def velocity_basis(tau: np.ndarray) -> Basis:
    """``h1``: slope 1 at 0; zero value and curvature at 0; zero value, slope and curvature at 1."""
    t2, t3 = tau * tau, tau * tau * tau
    value = tau - 6 * t3 + 8 * t3 * tau - 3 * t3 * t2
    slope = 1 - 18 * t2 + 32 * t3 - 15 * t3 * tau
    curve = -36 * tau + 96 * t2 - 60 * t3
    return value, slope, curve


def acceleration_basis(tau: np.ndarray) -> Basis:
    """``h2``: curvature 1 at 0; zero value and slope at 0; zero value, slope and curvature at 1."""
    t2, t3 = tau * tau, tau * tau * tau
    value = 0.5 * t2 - 1.5 * t3 + 1.5 * t3 * tau - 0.5 * t3 * t2
    slope = tau - 4.5 * t2 + 6 * t3 - 2.5 * t3 * tau
    curve = 1 - 9 * tau + 18 * t2 - 10 * t3
    return value, slope, curve


POSITION_BLEND_PEAK = 10.0 / math.sqrt(3.0)
"""max |h0''| on [0, 1] (at tau = 1/2 -+ sqrt(3)/6): a position offset ``d`` blended over ``T``
seconds adds at most ``d * POSITION_BLEND_PEAK / T^2`` of acceleration."""
VELOCITY_BLEND_PEAK = float(np.abs(velocity_basis(np.array([(192.0 - math.sqrt(10944.0)) / 360.0]))[2][0]))
"""max |h1''| on [0, 1] (about 3.94, where ``-36 + 192 tau - 180 tau^2`` vanishes): a velocity
offset ``w`` blended over ``T`` seconds adds at most ``w * VELOCITY_BLEND_PEAK / T`` of acceleration."""


def blend_duration(
    offset_position: np.ndarray,
    offset_velocity: np.ndarray,
    acceleration_budget: np.ndarray,
    nominal_s: float,
) -> float:
    """The blend's length: ``nominal_s`` seconds, or longer where blending these offsets that
    fast would add more acceleration to a joint than its budget. Solves
    ``|d| POSITION_BLEND_PEAK / T^2 + |w| VELOCITY_BLEND_PEAK / T <= budget`` per joint. A joint
    with no budget (zero, or not finite) does not lengthen the blend."""
    a = np.abs(np.asarray(offset_position, dtype=float)) * POSITION_BLEND_PEAK
    b = np.abs(np.asarray(offset_velocity, dtype=float)) * VELOCITY_BLEND_PEAK
    h = np.broadcast_to(np.asarray(acceleration_budget, dtype=float), a.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        needed = np.where((h > 0) & np.isfinite(h), (b + np.sqrt(b * b + 4.0 * h * a)) / (2.0 * h), 0.0)
    return max(nominal_s, float(np.max(needed, initial=0.0)))


def blend_offset(
    offset_position: np.ndarray,
    offset_velocity: np.ndarray,
    offset_acceleration: np.ndarray,
    duration_s: float,
    since_seam_s: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The blend's position, velocity and acceleration (each (M, J)) at ``since_seam_s`` (M,)
    seconds after the seam: the offsets at 0, zero from ``duration_s`` on."""
    T = duration_s
    tau = np.clip(np.asarray(since_seam_s, dtype=float) / T, 0.0, 1.0)[:, None]
    h0, h1, h2 = position_basis(tau), velocity_basis(tau), acceleration_basis(tau)
    d, w, c = (np.asarray(x, dtype=float)[None, :] for x in (offset_position, offset_velocity, offset_acceleration))
    position = d * h0[0] + w * T * h1[0] + c * T * T * h2[0]
    velocity = d * h0[1] / T + w * h1[1] + c * T * h2[1]
    acceleration = d * h0[2] / (T * T) + w * h1[2] / T + c * h2[2]
    return position, velocity, acceleration
