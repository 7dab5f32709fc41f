"""Joint limits: positions from the robot model, velocities/accelerations from joint_limits.yaml.

No robot description here carries velocity or acceleration limits (URDF's are often missing,
MJCF has none), so they come from a MoveIt-style ``joint_limits.yaml``::

    joint_limits:
      shoulder_pan_joint:
        has_velocity_limits: true
        max_velocity: 3.14159
        has_acceleration_limits: true
        max_acceleration: 5.0

``has_position_limits`` / ``min_position`` / ``max_position`` may narrow (never widen) the
model's position range. A joint with ``has_*_limits: false`` is unlimited in that quantity.
``check`` is vectorised: a 200 x 7 path is checked in tens of microseconds.
"""
from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import NDArray
import yaml
from runtime.errors import OptionError


@dataclass(frozen=True)
class JointLimit:
    name: str
    lower: float
    upper: float
    max_velocity: float = math.inf
    max_acceleration: float = math.inf


@dataclass(frozen=True)
class LimitViolation:
    """The first (earliest) point of a path that breaks a limit."""

    step: int
    time: float | None
    joint: str
    quantity: str
    """``position``, ``velocity`` or ``acceleration``."""
    value: float
    limit: float

    family = "joint limit"

    def __str__(self) -> str:
        when = f"step {self.step}" + (f" (t={self.time:.3f} s)" if self.time is not None else "")
        return f"{when}: {self.what}"

    @property
    def what(self) -> str:
        """The violation without its step: joint, quantity, value and limit."""
        unit = {"position": "rad", "velocity": "rad/s", "acceleration": "rad/s^2"}[self.quantity]
        relation = "below" if self.quantity == "position" and self.value < self.limit else "exceeds"
        return f"joint {self.joint} {self.quantity} {self.value:.4f} {unit} {relation} the limit {self.limit:.4f} {unit}"


@dataclass(frozen=True)
class JointLimits:
    joints: tuple[JointLimit, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @functools.cached_property
    def lower(self) -> NDArray[np.float64]:
        return _read_only(np.array([j.lower for j in self.joints]))

    @functools.cached_property
    def upper(self) -> NDArray[np.float64]:
        return _read_only(np.array([j.upper for j in self.joints]))

    @functools.cached_property
    def max_velocity(self) -> NDArray[np.float64]:
        return _read_only(np.array([j.max_velocity for j in self.joints]))

    @functools.cached_property
    def max_acceleration(self) -> NDArray[np.float64]:
        return _read_only(np.array([j.max_acceleration for j in self.joints]))

    def __getitem__(self, name: str) -> JointLimit:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(f"no limits for joint {name!r} (have: {', '.join(self.names)})")

    def subset(self, names: Sequence[str]) -> "JointLimits":
        """Limits of ``names``, in that order (e.g. a group's joints then the gripper)."""
        return JointLimits(tuple(self[n] for n in names))

    def check(
        self,
        positions: NDArray[np.float64],
        velocities: NDArray[np.float64] | None = None,
        accelerations: NDArray[np.float64] | None = None,
        times: NDArray[np.float64] | None = None,
        tolerance: float = 1e-9,
    ) -> LimitViolation | None:
        """The earliest violation in ``(N, dof)`` arrays whose columns follow ``names``.

        At one step, position is reported before velocity before acceleration.
        """
        found: list[tuple[int, int, int, str, float, float]] = []  # step, order, column, ...

        def earliest(mask: NDArray[np.bool_]) -> tuple[int, int] | None:
            hits = np.flatnonzero(mask)  # row-major: the first is the earliest step, then column
            return divmod(int(hits[0]), mask.shape[1]) if len(hits) else None

        q = self._as_rows(positions, "positions")
        lower, upper = self.lower, self.upper
        for bound, hit in ((lower, earliest(q < lower - tolerance)), (upper, earliest(q > upper + tolerance))):
            if hit:
                found.append((hit[0], 0, hit[1], "position", float(q[hit]), float(bound[hit[1]])))
        for order, (name, values, bound) in enumerate(
            (("velocity", velocities, self.max_velocity), ("acceleration", accelerations, self.max_acceleration)), 1
        ):
            if values is None:
                continue
            v = self._as_rows(values, name)
            hit = earliest(np.abs(v) > bound + tolerance)
            if hit:
                found.append((hit[0], order, hit[1], name, float(v[hit]), float(np.copysign(bound[hit[1]], v[hit]))))
        if not found:
            return None
        step, _, column, quantity, value, limit = min(found, key=lambda c: (c[0], c[1], c[2]))
        time = None if times is None else float(np.asarray(times)[step])
        return LimitViolation(step, time, self.joints[column].name, quantity, value, limit)

    def check_steps(self, positions: NDArray[np.float64], dt_s: float, tolerance: float = 1e-9) -> LimitViolation | None:
        """``check`` for targets one step of ``dt_s`` apart (a policy's column of gripper goals):
        the velocity into step k is ``(q_k - q_(k-1)) / dt_s`` (from step 1 on), the
        acceleration at step k the second difference over ``dt_s^2`` (from step 2 on), each
        reported at the step that asks for it."""
        q = self._as_rows(positions, "positions")
        velocities, accelerations = np.zeros_like(q), np.zeros_like(q)
        velocities[1:] = np.diff(q, axis=0) / dt_s
        accelerations[2:] = np.diff(q, 2, axis=0) / (dt_s * dt_s)
        return self.check(q, velocities, accelerations, tolerance=tolerance)

    def _as_rows(self, values: NDArray[np.float64], what: str) -> NDArray[np.float64]:
        a = np.atleast_2d(np.asarray(values, dtype=float))
        if a.shape[1] != len(self.joints):
            raise ValueError(f"{what} have {a.shape[1]} columns; expected {len(self.joints)} ({', '.join(self.names)})")
        return a


def _read_only(values: NDArray[np.float64]) -> NDArray[np.float64]:
    values.setflags(write=False)
    return values


def load_joint_limits(path: str | os.PathLike[str], position_limits: dict[str, tuple[float, float]]) -> JointLimits:
    """Combine model position limits ``{joint: (lower, upper)}`` with a joint_limits.yaml.

    Every joint in ``position_limits`` gets an entry; the YAML may not name unknown joints.
    """
    try:
        with open(path) as f:
            doc = yaml.safe_load(f) or {}
    except yaml.YAMLError as err:
        raise OptionError(f"{path}: not YAML: {err}") from None
    table = doc.get("joint_limits", {}) if isinstance(doc, dict) else None
    if not isinstance(table, dict):
        raise OptionError(f"{path}: 'joint_limits' must be a mapping of joint name -> limits")
    unknown = set(table) - set(position_limits)
    if unknown:
        raise OptionError(f"{path}: joint_limits names joints the model does not have: {sorted(unknown)}")
    out = []
    for name, (lower, upper) in position_limits.items():
        entry = table.get(name) or {}
        if not isinstance(entry, dict):
            raise OptionError(f"{path}: joint_limits.{name} must be a mapping")

        def number(key: str) -> float:
            try:
                value = float(entry[key])
            except KeyError:
                raise OptionError(f"{path}: joint_limits.{name} sets has_{key.split('_')[1]}_limits but no {key}") from None
            except (TypeError, ValueError):
                raise OptionError(f"{path}: joint_limits.{name}.{key} is not a number: {entry[key]!r}") from None
            if key.startswith("max_v") or key.startswith("max_a"):
                if value <= 0:
                    raise OptionError(f"{path}: joint_limits.{name}.{key} must be positive, got {value}")
            return value

        if entry.get("has_position_limits"):
            lower = max(lower, number("min_position"))
            upper = min(upper, number("max_position"))
        velocity = number("max_velocity") if entry.get("has_velocity_limits") else math.inf
        acceleration = number("max_acceleration") if entry.get("has_acceleration_limits") else math.inf
        out.append(JointLimit(name, float(lower), float(upper), velocity, acceleration))
    return JointLimits(tuple(out))
