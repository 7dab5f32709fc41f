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
"""
from __future__ import annotations

from dataclasses import dataclass, field

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


def _axis_values(name: str, values: list[float] | np.ndarray) -> np.ndarray:
    array = np.asarray(values, dtype=float).reshape(-1)
    if array.size != 6:
        raise ValueError(f"{name} needs 6 values (x y z rx ry rz) or none, got {array.size}")
    for i, value in enumerate(array):
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"{name}[{i}] ({AXES[i]}) must be finite and >= 0, got {value}")
    return array


@dataclass(frozen=True)
class AdmittanceState:
    """The Cartesian offset of the wrist from the reference, and its rate."""

    offset: np.ndarray = field(default_factory=lambda: np.zeros(6))
    rate: np.ndarray = field(default_factory=lambda: np.zeros(6))


def apply_deadband(wrench: np.ndarray, deadband: np.ndarray) -> np.ndarray:
    """Shrink each component toward zero by its deadband (continuous, no jump at the edge)."""
    wrench = np.asarray(wrench, dtype=float)
    return np.sign(wrench) * np.maximum(np.abs(wrench) - deadband, 0.0)


def admittance_step(state: AdmittanceState, wrench: np.ndarray, params: AdmittanceParams, dt: float) -> AdmittanceState:
    """Advance the per-axis mass-spring-damper by ``dt`` under ``wrench`` (semi-implicit Euler)."""
    force = apply_deadband(wrench, params.deadband)
    acceleration = (force - params.damping * state.rate - params.stiffness * state.offset) / params.mass
    rate = state.rate + acceleration * dt
    offset = state.offset + rate * dt
    clipped = np.clip(offset, -params.max_offset, params.max_offset)
    rate = np.where(clipped != offset, 0.0, rate)
    return AdmittanceState(clipped, rate)


def cartesian_to_joint(jacobian: np.ndarray, cartesian: np.ndarray, damping: float = 1e-3) -> np.ndarray:
    """Joint displacement producing ``cartesian`` at the wrist: damped least squares J^T (J J^T + l^2 I)^-1.

    ``cartesian`` is a 6-vector, or 6 x k to map k vectors at once.

    The damping keeps the mapping bounded near singularities, where an exact inverse would ask
    for huge joint motions to yield along a direction the arm can barely move in.
    """
    jacobian = np.asarray(jacobian, dtype=float)
    jjt = jacobian @ jacobian.T
    return jacobian.T @ np.linalg.solve(jjt + (damping**2) * np.eye(jjt.shape[0]), np.asarray(cartesian, dtype=float))
