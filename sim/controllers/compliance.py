"""Admittance: how far the arm yields to an external wrench (pure maths, no state machine).

Each Cartesian axis of the wrist (x y z rx ry rz) is a mass-spring-damper driven by the measured
wrench, M x'' + D x' + K x = F, integrated with semi-implicit Euler at the control rate. The
Cartesian offset x (and its rate) is mapped to joint offsets with a damped pseudo-inverse of the
wrist Jacobian, and the controller adds them to the trajectory's reference. A small deadband
keeps sensor noise and the gripper's own inertial forces from making the arm drift.

Defaults (``AdmittanceParams()``): 2000 N/m and 100 N m/rad stiffness with critical damping for
virtual masses of 5 kg and 0.05 kg m^2: a 20 N push moves the wrist 1 cm and it settles in about
0.2 s. The wrench and the Jacobian must be expressed in the same frame (``Hardware`` guarantees
it), and the wrench is the one the environment applies to the tool, so the arm moves along it.

The one approximation: the controller refreshes the damped pseudo-inverse every
``ControllersConfig.jacobian_refresh_period`` (10 ms, i.e. every 5 control steps) instead of every
step, since solving it each step was a fifth of the control loop's Python time. The Jacobian
moves ~1e-4 (relative) per 2 ms step while the arm moves, so the joint offset is off by under 1%
of itself: over the cube-stacking Objective at most 6e-6 rad on offsets up to 1.2e-3 rad
(median 0.02%). Set the period to 0 for the exact mapping at every step.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

AXES = ("x", "y", "z", "rx", "ry", "rz")


def critical_damping(stiffness: np.ndarray, mass: np.ndarray) -> np.ndarray:
    return 2.0 * np.sqrt(np.asarray(stiffness, dtype=float) * np.asarray(mass, dtype=float))


def _default_mass() -> np.ndarray:
    return np.array([5.0, 5.0, 5.0, 0.05, 0.05, 0.05])


def _default_stiffness() -> np.ndarray:
    return np.array([2000.0, 2000.0, 2000.0, 100.0, 100.0, 100.0])


@dataclass(frozen=True)
class AdmittanceParams:
    """Per-axis virtual mass, stiffness and damping, plus the deadband and offset limits."""

    stiffness: np.ndarray = field(default_factory=_default_stiffness)
    damping: np.ndarray = field(default_factory=lambda: critical_damping(_default_stiffness(), _default_mass()))
    mass: np.ndarray = field(default_factory=_default_mass)
    deadband: np.ndarray = field(default_factory=lambda: np.array([1.0, 1.0, 1.0, 0.1, 0.1, 0.1]))
    max_offset: np.ndarray = field(default_factory=lambda: np.array([0.1, 0.1, 0.1, 0.5, 0.5, 0.5]))

    def with_goal(self, stiffness: list[float] | np.ndarray, damping: list[float] | np.ndarray) -> AdmittanceParams:
        """These parameters with a goal's stiffness/damping (each empty = keep), validated.

        A goal giving stiffness but no damping gets critical damping for that stiffness.
        Raises ValueError naming the field and axis.
        """
        k = self.stiffness if len(stiffness) == 0 else _axis_values("admittance_stiffness", stiffness)
        if len(damping) == 0:
            d = self.damping if len(stiffness) == 0 else critical_damping(k, self.mass)
        else:
            d = _axis_values("admittance_damping", damping)
        for i in range(6):
            if k[i] == 0 and d[i] == 0:
                raise ValueError(
                    f"admittance axis {AXES[i]} has zero stiffness and zero damping: the arm would drift without bound"
                )
        return AdmittanceParams(k, d, self.mass, self.deadband, self.max_offset)

    @functools.cached_property
    def deadband_values(self) -> list[float]:
        """``deadband`` as Python floats (the fields are never changed in place)."""
        return np.asarray(self.deadband, dtype=float).tolist()

    @functools.cached_property
    def axes(self) -> list[tuple[float, float, float, float, float]]:
        """Per axis, as Python floats: deadband, mass, stiffness, damping, max_offset."""
        columns = (self.deadband, self.mass, self.stiffness, self.damping, self.max_offset)
        return list(zip(*(np.asarray(c, dtype=float).tolist() for c in columns)))


def _axis_values(name: str, values: list[float] | np.ndarray) -> np.ndarray:
    array = np.asarray(values, dtype=float).reshape(-1)
    if array.size != 6:
        raise ValueError(f"{name} needs 6 values (x y z rx ry rz) or none, got {array.size}")
    for i, value in enumerate(array):
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"{name}[{i}] ({AXES[i]}) must be finite and >= 0, got {value}")
    return array


REST_EPS = 1e-12
"""Metres, radians (and per second): an admittance whose offset and rate are below this on every
axis is at rest, exactly zero. The spring-damper only approaches zero asymptotically (into
subnormal numbers), so without this the mapping to joint offsets would run on ~1e-300 for the
whole run; 1e-12 m is nine orders below the sub-millimetre offsets the cell sees."""


@dataclass(frozen=True)
class AdmittanceState:
    """The Cartesian offset of the wrist from the reference, and its rate."""

    offset: np.ndarray = field(default_factory=lambda: np.zeros(6))
    rate: np.ndarray = field(default_factory=lambda: np.zeros(6))
    at_rest: bool = field(init=False)
    """Offset and rate all zero: the controller adds nothing to the reference."""
    _values: tuple[list[float], list[float]] = field(init=False, repr=False, compare=False)
    """``offset`` and ``rate`` as Python floats, for the next step's arithmetic."""

    def __post_init__(self) -> None:
        offsets, rates = np.asarray(self.offset, dtype=float).tolist(), np.asarray(self.rate, dtype=float).tolist()
        object.__setattr__(self, "_values", (offsets, rates))
        object.__setattr__(self, "at_rest", not (any(offsets) or any(rates)))


def admittance_step(state: AdmittanceState, wrench: np.ndarray, params: AdmittanceParams, dt: float) -> AdmittanceState:
    """Advance each axis' mass-spring-damper by ``dt`` under ``wrench`` (semi-implicit Euler).

    The deadband shrinks each wrench component toward zero (continuous, no jump at its edge); an
    axis whose offset reaches ``max_offset`` stops there, its rate zeroed. A state whose offset
    and rate fall below ``REST_EPS`` on every axis becomes rest (exact zeros); a state at rest
    under a wrench inside the deadband is returned unchanged, since the step would leave it at
    zero. Written per axis in plain floats: on six values, numpy's per-call overhead is twice the
    arithmetic, and the controller runs this 500 times a second.
    """
    wrench_values = np.asarray(wrench, dtype=float).tolist()
    if state.at_rest and inside_deadband(wrench_values, params.deadband_values):
        return state
    offsets, rates = [], []
    for w, x, v, (deadband, mass, stiffness, damping, limit) in zip(wrench_values, *state._values, params.axes):
        force = math.copysign(max(abs(w) - deadband, 0.0), w)
        v += (force - damping * v - stiffness * x) / mass * dt
        moved = x + v * dt
        clipped = min(max(moved, -limit), limit)
        offsets.append(clipped)
        rates.append(v if clipped == moved else 0.0)
    if max(map(abs, offsets + rates)) < REST_EPS:
        return AdmittanceState()
    return AdmittanceState(np.array(offsets), np.array(rates))


def inside_deadband(wrench: list[float], deadband: list[float]) -> bool:
    """Every axis of ``wrench`` (6 floats) within its deadband: an admittance at rest stays at
    rest. A NaN is outside. Written out: the controller asks every control step."""
    fx, fy, fz, tx, ty, tz = wrench
    bx, by, bz, rx, ry, rz = deadband
    return abs(fx) <= bx and abs(fy) <= by and abs(fz) <= bz and abs(tx) <= rx and abs(ty) <= ry and abs(tz) <= rz


@functools.cache
def _dgesv() -> Callable[..., tuple]:
    """LAPACK's ``dgesv``, imported on first use (``scipy.linalg`` takes ~0.2 s to import)."""
    from scipy.linalg import lapack

    return lapack.dgesv


def damped_pseudo_inverse(jacobian: np.ndarray, damping: float = 1e-3) -> np.ndarray:
    """The damped least-squares inverse J^T (J J^T + l^2 I)^-1 of a 6 x n Jacobian (n x 6).

    The damping keeps the mapping bounded near singularities, where an exact inverse would ask
    for huge joint motions to yield along a direction the arm can barely move in.

    J J^T + l^2 I is symmetric, so J^T (J J^T + l^2 I)^-1 = ((J J^T + l^2 I)^-1 J)^T: one solve,
    no explicit inverse. LAPACK's ``dgesv`` (the LU solver behind ``numpy.linalg.solve``) is called
    directly because numpy's wrapper costs five times the 6 x 6 solve itself, and the controller
    solves every few control steps.
    """
    jacobian = np.asarray(jacobian, dtype=float)
    rows = jacobian.shape[0]
    _, _, solution, info = _dgesv()(jacobian @ jacobian.T + (damping**2) * np.eye(rows), jacobian)
    if info != 0:  # the damping keeps a finite Jacobian's matrix regular
        raise np.linalg.LinAlgError(f"J J^T + l^2 I is singular (LAPACK dgesv info={info}): is the Jacobian finite?")
    return solution.T

