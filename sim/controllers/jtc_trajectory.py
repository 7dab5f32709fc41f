"""A trajectory as ros2_controllers' ``joint_trajectory_controller`` (JTC) holds and samples it.

Pure functions and an immutable ``JtcTrajectory``; no messages, no clock. What JTC does, read from
its ``trajectory.cpp`` and ``joint_trajectory_controller.cpp`` (Jazzy/Rolling with #2419):

- Between two points the spline kind follows the fields *both* points carry: positions only ->
  linear (velocity is the slope, no acceleration), positions and velocities -> cubic Hermite,
  positions, velocities and accelerations -> quintic Hermite. A trajectory may mix kinds (a merge
  puts the old points, a bridge point and the new points in one list).
- Before the first point, JTC interpolates from "the point before": the state it had when the
  trajectory was installed (the measured state by default: positions and velocities, no
  accelerations, which count as zero), with the first point's kind.
- After the last point it holds the last point (its velocities and accelerations as sent, zero
  where absent).
- **Merge at arrival** (``allow_trajectory_replacement`` true, #2419): a trajectory arriving while
  another one is executing takes over at its stamp (``now`` for a zero or past stamp). The old
  points between now and the handoff are kept, a bridge point sampled from the old spline at the
  handoff (position, velocity, acceleration) is added when it lies strictly before the new first
  point, then come the new points. JTC re-anchors the merged list at the control step that
  installs it; here it is installed at its arrival instant.
- **Hard replace** (``allow_trajectory_replacement`` false, or a release before #2419): the new
  trajectory starts at its stamp (the arrival instant for a zero stamp), from the point before
  taken at arrival.

Every segment is evaluated through the quintic Hermite of ``trajectory`` (a line and a cubic are
reproduced exactly by the quintic through their own end states), so the polynomial maths lives in
one place.
"""
from __future__ import annotations

import enum
from bisect import bisect_right
from dataclasses import dataclass, field

import numpy as np

from .trajectory import TIME_EPS, TrajectoryState, quintic_coefficients, quintic_powers


class SplineKind(enum.IntEnum):
    """JTC's interpolation between two points, from the fields both carry."""

    LINEAR = 1
    CUBIC = 3
    QUINTIC = 5


def segment_kind(has_velocity: bool, has_acceleration: bool) -> SplineKind:
    """The spline JTC uses between two points, given whether both carry velocities and accelerations.

    (JTC computes nothing for accelerations without velocities; such points are read as linear here.)"""
    if has_velocity and has_acceleration:
        return SplineKind.QUINTIC
    if has_velocity:
        return SplineKind.CUBIC
    return SplineKind.LINEAR


def segment_end_states(
    kind: np.ndarray, h: np.ndarray, p0: np.ndarray, v0: np.ndarray, a0: np.ndarray, p1: np.ndarray, v1: np.ndarray, a1: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Velocities and accelerations at both ends of each segment as JTC's spline of ``kind``
    (per segment, shape S) has them: the quintic through these end states is that spline.

    Linear: the slope at both ends, no acceleration. Cubic: the given velocities and the cubic's
    own end accelerations. Quintic: as given. Arrays are S x J; ``h`` is S."""
    hh = np.asarray(h, dtype=float)[:, None]
    dp = p1 - p0
    slope = dp / hh
    c2 = (3.0 * dp - (2.0 * v0 + v1) * hh) / hh**2
    c3 = (-2.0 * dp + (v0 + v1) * hh) / hh**3
    linear = (kind == SplineKind.LINEAR)[:, None]
    cubic = (kind == SplineKind.CUBIC)[:, None]
    v0e = np.where(linear, slope, v0)
    v1e = np.where(linear, slope, v1)
    a0e = np.where(linear, 0.0, np.where(cubic, 2.0 * c2, a0))
    a1e = np.where(linear, 0.0, np.where(cubic, 2.0 * c2 + 6.0 * c3 * hh, a1))
    return v0e, a0e, v1e, a1e


@dataclass(frozen=True)
class JtcPoints:
    """Trajectory points on absolute time in the controller's joint order. Rows of ``velocities``
    and ``accelerations`` are zero where a point does not carry that field (``has_*`` False)."""

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    has_velocity: np.ndarray
    has_acceleration: np.ndarray

    @classmethod
    def build(
        cls, times: np.ndarray, positions: np.ndarray, velocities: np.ndarray | None = None, accelerations: np.ndarray | None = None
    ) -> JtcPoints:
        """Points that all carry the same fields (None: absent)."""
        times = np.asarray(times, dtype=float).reshape(-1)
        positions = np.atleast_2d(np.asarray(positions, dtype=float))
        n = len(times)
        zeros = np.zeros_like(positions)
        return cls(
            times,
            positions,
            zeros if velocities is None else np.asarray(velocities, dtype=float),
            zeros if accelerations is None else np.asarray(accelerations, dtype=float),
            np.full(n, velocities is not None),
            np.full(n, accelerations is not None),
        )

    def __len__(self) -> int:
        return len(self.times)

    def select(self, keep: np.ndarray) -> JtcPoints:
        return JtcPoints(self.times[keep], self.positions[keep], self.velocities[keep], self.accelerations[keep],
                         self.has_velocity[keep], self.has_acceleration[keep])

    def shifted(self, seconds: float) -> JtcPoints:
        return JtcPoints(self.times + seconds, self.positions, self.velocities, self.accelerations, self.has_velocity, self.has_acceleration)

    @staticmethod
    def concatenate(parts: list[JtcPoints]) -> JtcPoints:
        return JtcPoints(*(np.concatenate([getattr(p, name) for p in parts]) for name in
                           ("times", "positions", "velocities", "accelerations", "has_velocity", "has_acceleration")))

    def state(self, k: int) -> TrajectoryState:
        """Point ``k`` as JTC outputs it when holding it: absent fields read as zero."""
        return TrajectoryState(self.positions[k].copy(), self.velocities[k].copy(), self.accelerations[k].copy())


@dataclass(frozen=True)
class JtcTrajectory:
    """The points JTC plays, and the point before them (``before_time``, ``before``)."""

    points: JtcPoints
    before_time: float
    before: TrajectoryState
    _knot_times: list[float] = field(init=False, repr=False, compare=False)
    _coefficients: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pts = self.points
        if len(pts) == 0:
            raise ValueError("a trajectory needs at least one point")
        if np.any(np.diff(pts.times) <= 0):
            raise ValueError("trajectory point times must increase strictly")
        if self.before_time < pts.times[0] - TIME_EPS:
            # The segment from the point before takes the first point's kind (JTC zero-fills the
            # point before's missing fields; its accelerations are zero when it is a measured state).
            first = JtcPoints(
                np.array([self.before_time]), self.before.position[None, :], self.before.velocity[None, :],
                self.before.acceleration[None, :], pts.has_velocity[:1], pts.has_acceleration[:1],
            )
            pts = JtcPoints.concatenate([first, pts])
        times = pts.times
        if len(times) > 1:
            h = np.diff(times)
            kind = np.array([segment_kind(bool(v), bool(a)) for v, a in
                             zip(pts.has_velocity[:-1] & pts.has_velocity[1:], pts.has_acceleration[:-1] & pts.has_acceleration[1:])])
            p0, p1 = pts.positions[:-1], pts.positions[1:]
            v0e, a0e, v1e, a1e = segment_end_states(kind, h, p0, pts.velocities[:-1], pts.accelerations[:-1],
                                                    p1, pts.velocities[1:], pts.accelerations[1:])
            coefficients = quintic_coefficients(h, p0, v0e, a0e, p1, v1e, a1e)
        else:
            coefficients = np.empty((0, 6, pts.positions.shape[1]))
        object.__setattr__(self, "_knot_times", times.tolist())
        object.__setattr__(self, "_coefficients", coefficients)

    @classmethod
    def hold(cls, t: float, position: np.ndarray) -> JtcTrajectory:
        """Hold ``position`` at rest from ``t`` (JTC's hold-position trajectory)."""
        q = np.asarray(position, dtype=float).reshape(1, -1)
        zeros = np.zeros_like(q)
        return cls(JtcPoints.build(np.array([float(t)]), q, zeros, zeros), float(t), TrajectoryState(q[0], zeros[0], zeros[0]))

    @property
    def end_time(self) -> float:
        return float(self.points.times[-1])

    @property
    def num_joints(self) -> int:
        return self.points.positions.shape[1]

    def sample(self, t: float) -> TrajectoryState:
        """What JTC commands at ``t``: the segment's spline, the last point after the end (before
        the first knot, the first knot's state: JTC does not sample there)."""
        knots = self._knot_times
        if t >= knots[-1]:
            return self.points.state(len(self.points) - 1)
        k = max(bisect_right(knots, t) - 1, 0)
        position, velocity, acceleration = quintic_powers(max(t - knots[k], 0.0)) @ self._coefficients[k]
        return TrajectoryState(position, velocity, acceleration)

    def sample_many(self, times: np.ndarray) -> TrajectoryState:
        """``sample`` at each of ``times``: (N, J) positions, velocities, accelerations."""
        states = [self.sample(float(t)) for t in np.asarray(times, dtype=float)]
        return TrajectoryState(np.array([s.position for s in states]), np.array([s.velocity for s in states]),
                               np.array([s.acceleration for s in states]))


def handoff_time(stamp_s: float, now_s: float) -> float:
    """When a trajectory stamped ``stamp_s`` that arrives at ``now_s`` takes over (both modes):
    its stamp when that is still ahead, else now (a zero stamp means now)."""
    return stamp_s if stamp_s > now_s else now_s


def merge_at_arrival(current: JtcTrajectory, new: JtcPoints, stamp_s: float, now_s: float, before: TrajectoryState) -> JtcTrajectory:
    """``new`` (times from its start) merged into ``current`` as JTC with
    ``allow_trajectory_replacement`` does when it arrives at ``now_s``: the old points in
    (now, handoff), a bridge point sampled from ``current`` at the handoff when that lies strictly
    before the first new point, then the new points from the handoff. ``before`` is the state at
    arrival (the merged trajectory's point before)."""
    start = handoff_time(stamp_s, now_s)
    placed = new.shifted(start)
    old = current.points
    parts = [old.select((old.times > now_s + TIME_EPS) & (old.times < start - TIME_EPS))]
    if start < placed.times[0] - TIME_EPS:
        bridge = current.sample(start)
        parts.append(JtcPoints(np.array([start]), bridge.position[None, :], bridge.velocity[None, :],
                               bridge.acceleration[None, :], np.array([True]), np.array([True])))
    parts.append(placed)
    return JtcTrajectory(JtcPoints.concatenate(parts), now_s, before)


def replace_at_arrival(new: JtcPoints, stamp_s: float, now_s: float, before: TrajectoryState) -> JtcTrajectory:
    """``new`` (times from its start) as the whole trajectory, as JTC without trajectory
    replacement installs it at ``now_s``: it starts at its stamp (now for a zero stamp), from the
    point before taken at arrival; points already past are played from where the clock is."""
    start = stamp_s if stamp_s != 0.0 else now_s
    return JtcTrajectory(new.shifted(start), now_s, before)
