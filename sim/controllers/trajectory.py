"""Joint trajectories for the simulated controllers: sampling, stitching at a seam, smooth stops.

Pure functions and an immutable ``Trajectory``; no messages, no clock, no hardware, so the maths
is tested on its own and the controllers stay thin state machines.

Every point of a ``Trajectory`` carries position, velocity and acceleration, and consecutive
points are joined by quintic Hermite polynomials. Quintic (rather than cubic) because a piece of
a quintic (or of a cubic) is reproduced exactly by the quintic through its end states: cutting a
trajectory at any instant and continuing it from its sampled state keeps its shape, which is what
stitching at a seam needs. Missing velocities or accelerations are filled in by finite
differences (``numpy.gradient``, second order inside, one-sided at the ends); a positions-only
trajectory comes to rest at its last point, which the controller then holds.

Times are absolute, on the runtime clock (the goal's seam stamp plus ``time_from_start``).
"""
from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, field

import numpy as np

from behaviors.execute_policy import seam
from behaviors.execute_policy.seam import blend_offset
from runtime.errors import ObjectiveError

TIME_EPS = 1e-6  # seconds: stamps travel as integer nanoseconds, rounded on both sides
"""Seconds within which two instants are the same (seam exactly at a point, at the end)."""


class SeamError(ObjectiveError, ValueError):
    """A new trajectory cannot take over from the current one at the requested seam."""


@dataclass(frozen=True)
class TrajectoryState:
    """Position, velocity and acceleration of every joint at one instant."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


def quintic_coefficients(
    h: np.ndarray, p0: np.ndarray, v0: np.ndarray, a0: np.ndarray, p1: np.ndarray, v1: np.ndarray, a1: np.ndarray
) -> np.ndarray:
    """Coefficients c0..c5 of p(tau) = sum c_k tau^k matching both end states, for every piece at once.

    ``h`` (shape S) holds the pieces' durations and the states have shape S x J; the result is
    S x 6 x J. One vectorised pass over all pieces: a goal carries hundreds of points, and a
    Python loop over them cost milliseconds per goal.
    """
    h = np.asarray(h, dtype=float)[:, None]
    dp = p1 - p0
    c3 = (20 * dp - (8 * v1 + 12 * v0) * h - (3 * a0 - a1) * h**2) / (2 * h**3)
    c4 = (-30 * dp + (14 * v1 + 16 * v0) * h + (3 * a0 - 2 * a1) * h**2) / (2 * h**4)
    c5 = (12 * dp - 6 * (v1 + v0) * h + (a1 - a0) * h**2) / (2 * h**5)
    return np.stack([p0, v0, a0 / 2.0, c3, c4, c5], axis=1)


def quintic_powers(tau: float) -> np.ndarray:
    """The 3 x 6 matrix whose product with a piece's coefficients (6 x J) gives position,
    velocity and acceleration at ``tau``: one small matmul instead of three Horner chains."""
    return np.array(_quintic_power_values(tau)).reshape(3, 6)


def _quintic_power_values(tau: float) -> tuple[float, ...]:
    """``quintic_powers(tau)``'s 18 entries, row by row, as Python floats (numpy builds an
    array from one flat sequence in a fraction of the time it takes on nested lists)."""
    t2 = tau * tau
    t3 = t2 * tau
    t4 = t3 * tau
    return (
        1.0, tau, t2, t3, t4, t4 * tau,
        0.0, 1.0, 2.0 * tau, 3.0 * t2, 4.0 * t3, 5.0 * t4,
        0.0, 0.0, 2.0, 6.0 * tau, 12.0 * t2, 20.0 * t3,
    )


@dataclass(frozen=True)
class Trajectory:
    """Knots (absolute times, positions, velocities, accelerations) joined by quintic Hermite pieces.

    Before the first knot and after the last, the trajectory holds that knot's position at rest:
    a finished trajectory is a hold.
    """

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    _coefficients: np.ndarray = field(init=False, repr=False, compare=False)
    _knot_times: list[float] = field(init=False, repr=False, compare=False)
    """``times`` as Python floats: the control loop looks up its piece 500 times a second, and
    ``bisect`` on a list is ~10x cheaper than ``numpy.searchsorted`` for one scalar."""

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=float).reshape(-1)
        n = times.size
        if n == 0:
            raise ValueError("a trajectory needs at least one point")
        arrays = {}
        for name in ("positions", "velocities", "accelerations"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.ndim != 2 or value.shape[0] != n:
                raise ValueError(f"trajectory {name} must have shape ({n}, joints), got {value.shape}")
            if not np.all(np.isfinite(value)):
                raise ValueError(f"trajectory {name} contain non-finite values")
            arrays[name] = value
        if arrays["velocities"].shape != arrays["positions"].shape or arrays["accelerations"].shape != arrays["positions"].shape:
            raise ValueError("trajectory positions, velocities and accelerations must have the same shape")
        if not np.all(np.isfinite(times)):
            raise ValueError("trajectory times contain non-finite values")
        steps = np.diff(times)
        if np.any(steps <= 0):
            k = int(np.argmax(steps <= 0)) + 1
            raise ValueError(f"trajectory times must increase strictly: point {k} at t={times[k]:.6f} s follows t={times[k - 1]:.6f} s")
        object.__setattr__(self, "times", times)
        for name, value in arrays.items():
            object.__setattr__(self, name, value)
        p, v, a = arrays["positions"], arrays["velocities"], arrays["accelerations"]
        coefficients = quintic_coefficients(steps, p[:-1], v[:-1], a[:-1], p[1:], v[1:], a[1:])
        object.__setattr__(self, "_coefficients", coefficients)
        object.__setattr__(self, "_knot_times", times.tolist())

    # -- construction ---
    @classmethod
    def from_points(
        cls,
        times: np.ndarray,
        positions: np.ndarray,
        velocities: np.ndarray | None = None,
        accelerations: np.ndarray | None = None,
    ) -> Trajectory:
        """Build from waypoints, filling missing velocities/accelerations by finite differences.

        Without velocities the trajectory comes to rest at its last point (velocity and
        acceleration zero there), since the controller holds that point afterwards.
        """
        times = np.asarray(times, dtype=float).reshape(-1)
        positions = np.atleast_2d(np.asarray(positions, dtype=float))
        at_rest_at_end = velocities is None
        if velocities is None:
            velocities = _differentiate(positions, times)
            velocities[-1] = 0.0
        velocities = np.atleast_2d(np.asarray(velocities, dtype=float))
        if accelerations is None:
            accelerations = _differentiate(velocities, times)
            if at_rest_at_end:
                accelerations[-1] = 0.0
        return cls(times, positions, velocities, np.atleast_2d(np.asarray(accelerations, dtype=float)))

    @classmethod
    def hold(cls, t: float, position: np.ndarray) -> Trajectory:
        """Stay at ``position`` (at rest) from ``t`` on."""
        q = np.asarray(position, dtype=float).reshape(1, -1)
        return cls(np.array([float(t)]), q, np.zeros_like(q), np.zeros_like(q))

    # -- queries ---
    @property
    def num_joints(self) -> int:
        return int(self.positions.shape[1])

    @property
    def start_time(self) -> float:
        return self._knot_times[0]

    @property
    def end_time(self) -> float:
        return self._knot_times[-1]

    def sample(self, t: float) -> TrajectoryState:
        """The state at absolute time ``t``; outside the knots, the nearest end point's position at rest."""
        knots = self._knot_times
        if not knots[0] < t < knots[-1]:
            return self._sample_end(t)
        k = bisect_right(knots, t) - 1
        position, velocity, acceleration = quintic_powers(t - knots[k]) @ self._coefficients[k]
        return TrajectoryState(position, velocity, acceleration)

    def sample_many(self, times: list[float]) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities at each of ``times`` (increasing; two N x J arrays), row k
        equal bit for bit to ``sample(times[k])``: one vectorised pass for a tick's control steps."""
        knots = self._knot_times
        if not times:
            return np.empty((0, self.num_joints)), np.empty((0, self.num_joints))
        if not knots[0] < times[0] <= times[-1] < knots[-1]:  # an end of the trajectory is in reach
            states = [self.sample(t) for t in times]
            return np.array([s.position for s in states]), np.array([s.velocity for s in states])
        pieces = [bisect_right(knots, t) - 1 for t in times]
        values: list[float] = []
        for t, k in zip(times, pieces):
            values += _quintic_power_values(t - knots[k])
        powers = np.fromiter(values, float, len(values)).reshape(len(times), 3, 6)
        # One matmul per row, as ``sample`` does (a broadcast product of N x 3 x 6 by 6 x J is
        # one BLAS call of 3N rows, which does not always round like N calls of 3 rows).
        state = np.matmul(powers, self._coefficients[pieces])  # N x 3 x J
        return state[:, 0], state[:, 1]

    def _sample_end(self, t: float) -> TrajectoryState:
        """At the first or last knot its own state; before or after them, its position at rest."""
        k = 0 if t <= self._knot_times[0] else -1
        if t == self._knot_times[k]:
            return TrajectoryState(self.positions[k].copy(), self.velocities[k].copy(), self.accelerations[k].copy())
        q = self.positions[k].copy()
        return TrajectoryState(q, np.zeros_like(q), np.zeros_like(q))

    def trimmed_before(self, t: float) -> Trajectory:
        """Drop knots that can no longer be sampled from ``t`` on (keeps the piece containing ``t``)."""
        keep_from = max(bisect_right(self._knot_times, t) - 1, 0)
        if keep_from == 0:
            return self
        return Trajectory(
            self.times[keep_from:], self.positions[keep_from:], self.velocities[keep_from:], self.accelerations[keep_from:]
        )


def _differentiate(values: np.ndarray, times: np.ndarray) -> np.ndarray:
    if times.size < 2:
        return np.zeros_like(values)
    return np.gradient(values, times, axis=0, edge_order=1)


def _joint_label(joint_names: tuple[str, ...] | None, j: int) -> str:
    return joint_names[j] if joint_names is not None else f"joint {j}"


DEVIATION_EPS = 1e-9
"""Radians (and rad/s, rad/s^2) below which a seam's deviation is nothing to absorb."""


def blend_duration(deviation: TrajectoryState, max_acceleration: float, min_duration: float) -> float:
    """Seconds over which the offset starting at ``deviation`` fades to zero, its position and
    velocity parts adding at most ``max_acceleration`` rad/s^2 to any joint
    (``behaviors.execute_policy.seam.blend_duration``: ExecutePolicy's seam blend); its acceleration part adds no more than itself."""
    if max_acceleration <= 0:
        raise ValueError(f"max_acceleration must be > 0, got {max_acceleration}")
    return seam.blend_duration(deviation.position, deviation.velocity, max_acceleration, max(min_duration, 1e-3))


def absorb_deviation(new: Trajectory, start: float, deviation: TrajectoryState, duration: float) -> Trajectory:
    """``new`` plus the seam blend (``behaviors.execute_policy.seam.blend_offset``) that equals ``deviation``
    at ``start`` and fades to zero (with its velocity and acceleration) at ``start + duration``,
    after which ``new`` is unchanged.

    The blend is one quintic; a knot is added at its end (``new``'s own state there), so every
    piece inside the window is a quintic plus a quintic and the Hermite pieces reproduce the sum
    exactly. A window reaching past ``new``'s end is cut there.
    """
    end = min(start + duration, new.end_time)
    if end <= start + TIME_EPS:
        return new
    times, positions, velocities, accelerations = new.times, new.positions, new.velocities, new.accelerations
    if not np.any(np.abs(times - end) <= TIME_EPS):
        k = int(np.searchsorted(times, end))
        state = new.sample(end)
        times = np.insert(times, k, end)
        positions = np.insert(positions, k, state.position, axis=0)
        velocities = np.insert(velocities, k, state.velocity, axis=0)
        accelerations = np.insert(accelerations, k, state.acceleration, axis=0)
    inside = np.flatnonzero((times >= start - TIME_EPS) & (times < end - TIME_EPS))
    offset = blend_offset(deviation.position, deviation.velocity, deviation.acceleration, duration,
                          np.maximum(times[inside] - start, 0.0))
    positions, velocities, accelerations = positions.copy(), velocities.copy(), accelerations.copy()
    positions[inside] += offset[0]
    velocities[inside] += offset[1]
    accelerations[inside] += offset[2]
    return Trajectory(times, positions, velocities, accelerations)


def stitch(
    current: Trajectory,
    new: Trajectory,
    seam_time: float,
    path_tolerance: float = 0.0,
    joint_names: tuple[str, ...] | None = None,
    allow_after_end: bool = False,
    check_velocity: bool = True,
    blend_acceleration: float = 1.0,
    min_blend_time: float = 0.05,
) -> Trajectory:
    """Follow ``current`` until ``seam_time`` and ``new`` after it, continuous at the seam.

    Checks, raising ``SeamError`` with a message a user can act on:
    - the seam must not lie after the end of ``current`` (unless ``allow_after_end``: an idle
      controller holding its last point may start a new motion later);
    - when ``new`` has a point at the seam itself and ``path_tolerance`` > 0, that point's position
      and velocity must agree with ``current``'s sample there within ``path_tolerance`` (radians,
      and radians per second for the velocity, as the guide's goal_path_tolerance). With
      ``check_velocity`` False only positions are compared (for a new trajectory whose velocities
      were estimated by finite differences, not stated by its sender).

    The knot at the seam is ``current``'s own state there (position, velocity, acceleration), so
    the result is continuous up to acceleration and identical to ``current`` before the seam.
    When ``new`` has a point at the seam that differs from that state (within the tolerance just
    checked), the difference is not closed in ``new``'s first interval (a 3 mrad gap over a 10 ms
    interval asks 150 rad/s^2) but fades out as an offset on ``new`` that adds at most
    ``blend_acceleration`` rad/s^2 for its position and velocity parts (``blend_duration``, at
    least ``min_blend_time``): the typical
    case is a first goal that starts from the measured position while the controller holds its
    reference a few mrad away (the servos sag under the gripper's weight). When ``new`` starts
    after the seam, the piece between the seam and its first point bridges from ``current``'s
    state, as ros2_control's JTC does from the state at the goal's stamp.
    """
    if new.num_joints != current.num_joints:
        raise SeamError(f"the new trajectory has {new.num_joints} joints, the current one {current.num_joints}")
    if seam_time > current.end_time + TIME_EPS and not allow_after_end:
        raise SeamError(
            "seam time exceeds the end of the current trajectory "
            f"(seam t={seam_time:.4f} s, trajectory ends at t={current.end_time:.4f} s)"
        )
    if new.start_time < seam_time - TIME_EPS:
        raise SeamError(f"the new trajectory starts at t={new.start_time:.4f} s, before the seam t={seam_time:.4f} s")
    # A seam at the very end (up to the nanosecond rounding of stamps) joins the last point's
    # state, not the hold that follows it.
    at_seam = current.sample(min(seam_time, current.end_time) if seam_time <= current.end_time + TIME_EPS else seam_time)
    new_starts_at_seam = new.start_time <= seam_time + TIME_EPS
    if new_starts_at_seam and path_tolerance > 0:
        comparisons = [("position", "rad", at_seam.position, new.positions[0])]
        if check_velocity:
            comparisons.append(("velocity", "rad/s", at_seam.velocity, new.velocities[0]))
        for label, unit, ours, theirs in comparisons:
            deviation = np.abs(theirs - ours)
            j = int(np.argmax(deviation))
            if deviation[j] > path_tolerance:
                raise SeamError(
                    f"{label} deviation at the seam on {_joint_label(joint_names, j)}: {deviation[j]:.4f} {unit} "
                    f"exceeds the path tolerance {path_tolerance:.4f} (seam t={seam_time:.4f} s; "
                    f"current {ours[j]:.4f}, new {theirs[j]:.4f})"
                )
    if new_starts_at_seam:
        deviation = TrajectoryState(
            at_seam.position - new.positions[0], at_seam.velocity - new.velocities[0], at_seam.acceleration - new.accelerations[0]
        )
        if max(np.max(np.abs(deviation.position)), np.max(np.abs(deviation.velocity)), np.max(np.abs(deviation.acceleration))) > DEVIATION_EPS:
            duration = blend_duration(deviation, blend_acceleration, min_blend_time)
            new = absorb_deviation(new, new.start_time, deviation, duration)
    before = current.times < seam_time - TIME_EPS
    after = new.times > seam_time + TIME_EPS
    return Trajectory(
        np.concatenate([current.times[before], [seam_time], new.times[after]]),
        np.vstack([current.positions[before], at_seam.position, new.positions[after]]),
        np.vstack([current.velocities[before], at_seam.velocity, new.velocities[after]]),
        np.vstack([current.accelerations[before], at_seam.acceleration, new.accelerations[after]]),
    )


def stop_trajectory(state: TrajectoryState, t: float, stop_time: float) -> Trajectory:
    """Decelerate from ``state`` at ``t`` to rest within ``stop_time`` seconds, then hold.

    The stopping distance is that of a constant deceleration (v * T / 2); the quintic joining
    the two states keeps position, velocity and acceleration continuous, so an abort never
    commands a jump.
    """
    if stop_time <= 0:
        raise ValueError(f"stop_time must be > 0, got {stop_time}")
    q = np.asarray(state.position, dtype=float)
    v = np.asarray(state.velocity, dtype=float)
    if not np.any(v) and not np.any(state.acceleration):
        return Trajectory.hold(t, q)
    end = q + v * stop_time / 2.0
    zeros = np.zeros_like(q)
    return Trajectory(
        np.array([t, t + stop_time]),
        np.vstack([q, end]),
        np.vstack([v, zeros]),
        np.vstack([np.asarray(state.acceleration, dtype=float), zeros]),
    )


def path_violation(
    actual: np.ndarray, reference: np.ndarray, tolerance: float, joint_names: tuple[str, ...] | None = None
) -> str | None:
    """The worst joint whose |actual - reference| exceeds ``tolerance`` (0 = no check), or None.

    A non-finite error counts as the worst. Plain floats: the controller checks every control step.
    """
    actual_values, reference_values = np.asarray(actual, dtype=float).tolist(), np.asarray(reference, dtype=float).tolist()
    if within_path_tolerance(actual_values, reference_values, tolerance):
        return None
    errors = [abs(a - r) for a, r in zip(actual_values, reference_values)]
    j = _worst_index(errors)
    return f"{_joint_label(joint_names, j)}: error {errors[j]:.4f} rad exceeds the path tolerance {tolerance:.4f} rad"


def within_path_tolerance(actual: list[float], reference: list[float], tolerance: float) -> bool:
    """``path_violation(actual, reference, tolerance) is None``: every |actual - reference|
    within ``tolerance`` (0 = no check; a NaN is not within), on plain floats (the controller's
    quick path checks every control step)."""
    if tolerance <= 0:
        return True
    for a, r in zip(actual, reference):
        if not abs(a - r) <= tolerance:
            return False
    return True


def _worst_index(values: list[float]) -> int:
    """Index of the largest value, a NaN counting as larger than anything (as ``numpy.argmax``)."""
    for k, value in enumerate(values):
        if math.isnan(value):
            return k
    return values.index(max(values))


WRENCH_AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
WRENCH_UNITS = ("N", "N", "N", "N m", "N m", "N m")


def wrench_violation(wrench: np.ndarray, thresholds: np.ndarray | None) -> str | None:
    """The axis whose |wrench| exceeds its absolute threshold the most (relative), or None.

    A NaN reading counts as exceeding. Plain floats: the controller checks every control step.
    """
    if thresholds is None or len(thresholds) == 0:
        return None
    values = np.asarray(wrench, dtype=float).tolist()
    limits = np.asarray(thresholds, dtype=float).tolist()
    if within_thresholds(values, limits):
        return None
    i = _worst_index([abs(w) / limit for w, limit in zip(values, limits)])
    return (
        f"{WRENCH_AXES[i]} = {values[i]:.2f} {WRENCH_UNITS[i]}, "
        f"beyond the absolute threshold {limits[i]:.2f} {WRENCH_UNITS[i]}"
    )


def within_thresholds(values: list[float], limits: list[float] | None) -> bool:
    """``wrench_violation(values, limits) is None`` for a wrench of 6 floats (limits None or
    empty: none). Written out: the controller asks every control step."""
    if not limits:
        return True
    fx, fy, fz, tx, ty, tz = values
    lx, ly, lz, mx, my, mz = limits
    return abs(fx) <= lx and abs(fy) <= ly and abs(fz) <= lz and abs(tx) <= mx and abs(ty) <= my and abs(tz) <= mz
