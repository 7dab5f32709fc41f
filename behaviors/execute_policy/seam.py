"""The seam: how a chunk joins the motion the controller plays. Pure functions, no state.

At the seam the chunk's smoothed motion differs from the sent one (``state_at``: where the arm
is and how fast it moves when the goal takes over) by an offset in position ``d``, velocity
``w`` and acceleration ``c`` (per joint). The blend adds to the chunk's motion the quintic
``d h0(tau) + w T h1(tau) + c T^2 h2(tau)``, ``tau = (t - seam) / T`` (``blend_offset``): it equals
the offset at the seam and fades to zero, with its slope and curvature, ``T`` seconds later.
``h0`` and ``h1`` have zero curvature at the seam, so a position and a velocity offset add no
acceleration step there. ``T`` is half the window (``nominal_blend_s``), longer where blending
that fast would take more than ``BLEND_SHARE`` of the acceleration the chunk's own motion leaves
free (``blend_duration``, a closed form of the quintic's peaks; ``join_at_seam``). The joined
motion is a ``ChunkMotion``. A chunk whose seam comes after the motion still playing has ended
cannot join it (``motion_ends_first``). The new goal takes over at the seam, or later within the
seam's step when the chunk found the arm at rest (``take_over_time``).

The simulated trajectory controllers blend a new goal into the one they play with the same
quintic (``sim/controllers/trajectory.py``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..action_goal import GoalState
from .step_spline import StepSpline
from .tail import runout_warp

if TYPE_CHECKING:
    from .at_rest import Arrival
    from .config import ShapingConfig
    from .stream import StepGrid, Window
    from .tail import Tail

Basis = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]
"""A basis function's value, slope and curvature with respect to ``tau``."""


def position_basis(tau: NDArray[np.float64]) -> Basis:
    """``h0``: value 1 at 0; zero slope and curvature at 0; zero value, slope and curvature at 1."""
    t2, t3 = tau * tau, tau * tau * tau
    value = 1 - 10 * t3 + 15 * t3 * tau - 6 * t3 * t2
    slope = -30 * t2 + 60 * t3 - 30 * t3 * tau
    curve = -60 * tau + 180 * t2 - 120 * t3
    return value, slope, curve


def velocity_basis(tau: NDArray[np.float64]) -> Basis:
    """``h1``: slope 1 at 0; zero value and curvature at 0; zero value, slope and curvature at 1."""
    t2, t3 = tau * tau, tau * tau * tau
    value = tau - 6 * t3 + 8 * t3 * tau - 3 * t3 * t2
    slope = 1 - 18 * t2 + 32 * t3 - 15 * t3 * tau
    curve = -36 * tau + 96 * t2 - 60 * t3
    return value, slope, curve


def acceleration_basis(tau: NDArray[np.float64]) -> Basis:
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
    offset_position: NDArray[np.float64],
    offset_velocity: NDArray[np.float64],
    acceleration_budget: NDArray[np.float64] | float,
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
    offset_position: NDArray[np.float64],
    offset_velocity: NDArray[np.float64],
    offset_acceleration: NDArray[np.float64] | None,
    duration_s: float,
    since_seam_s: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The blend's position, velocity and acceleration (each (M, J)) at ``since_seam_s`` (M,)
    seconds after the seam: the offsets at 0, zero from ``duration_s`` on. An
    ``offset_acceleration`` of None is a zero one."""
    T = duration_s
    tau = np.clip(np.asarray(since_seam_s, dtype=float) / T, 0.0, 1.0)[:, None]
    h0, h1 = position_basis(tau), velocity_basis(tau)
    d, w = np.asarray(offset_position, dtype=float)[None, :], np.asarray(offset_velocity, dtype=float)[None, :]
    position = d * h0[0] + w * T * h1[0]
    velocity = d * h0[1] / T + w * h1[1]
    acceleration = d * h0[2] / (T * T) + w * h1[2] / T
    if offset_acceleration is not None:
        h2 = acceleration_basis(tau)
        c = np.asarray(offset_acceleration, dtype=float)[None, :]
        position += c * T * T * h2[0]
        velocity += c * T * h2[1]
        acceleration += c * h2[2]
    return position, velocity, acceleration


NOMINAL_BLEND_WINDOWS = 0.5
"""The blend lasts this share of the window (at least one step) unless the offset needs longer."""


def nominal_blend_s(window_steps: int, dt: float) -> float:
    """How long the blend lasts unless the offset needs longer: half the window, at least a step."""
    return max(dt, NOMINAL_BLEND_WINDOWS * window_steps * dt)


BLEND_SHARE = 0.5
"""The blend may use this share of the acceleration the chunk's own motion leaves free (half,
as the runout brakes with half the limit): a long way to join is covered gently."""


def chunk_acceleration_peak(spline: StepSpline, dt: float, from_step: float) -> NDArray[np.float64]:
    """Per joint, the largest acceleration (rad/s^2) of the smoothed chunk from ``from_step`` to
    its last step. Its second derivative is piecewise linear between the integer steps (the
    knots), so the steps and ``from_step`` are where it peaks."""
    last = spline.last_step
    steps = np.unique(np.concatenate([[min(from_step, last)], np.arange(math.ceil(from_step), math.floor(last) + 1)]))
    peaks: NDArray[np.float64] = np.abs(np.atleast_2d(spline(steps, nu=2))).max(axis=0) / (dt * dt)
    return peaks


def join_at_seam(
    spline: StepSpline,
    dt: float,
    chunk_start: float,
    seam: float,
    end: float,
    sent_position: NDArray[np.float64],
    sent_velocity: NDArray[np.float64],
    nominal_s: float,
    max_acceleration: NDArray[np.float64] | None = None,
) -> ChunkMotion:
    """The chunk's motion from ``seam`` to ``end``, continuous in position and velocity with
    the sent motion's state (``sent_position``, ``sent_velocity``) at the seam.

    The offset between the two is blended out (``blend_offset``) over ``nominal_s``
    seconds; with ``max_acceleration`` (per joint) over longer where that would take more than
    ``BLEND_SHARE`` of the acceleration the chunk leaves free: a chunk that starts away from where the
    arm is (a policy that re-planned, or ran ahead of an arm that paused) joins more slowly
    instead of being planned over the limits."""
    if not end > seam:
        raise ValueError(f"empty window: seam t={seam:.3f} s, end t={end:.3f} s")
    k = (seam - chunk_start) / dt
    offset_p = np.asarray(sent_position, dtype=float) - spline(k)
    offset_v = np.asarray(sent_velocity, dtype=float) - spline(k, nu=1) / dt
    if max_acceleration is not None:
        headroom = np.asarray(max_acceleration, dtype=float) - chunk_acceleration_peak(spline, dt, k)
        duration = blend_duration(offset_p, offset_v, BLEND_SHARE * headroom, nominal_s)
    else:
        duration = nominal_s
    return ChunkMotion(spline, dt, chunk_start, seam, end, offset_p, offset_v, max(duration, 1e-6))


@dataclass(frozen=True)
class ChunkMotion:
    """One chunk's motion on the clock: the smoothed chunk plus the seam blend, then its tail or
    its stop at the window's end.

    ``chunk_start`` is the clock time of the chunk's step 0 (the request instant); the motion
    is defined on ``[seam, end]``.
    """

    spline: StepSpline
    dt: float
    chunk_start: float
    seam: float
    end: float
    offset_position: NDArray[np.float64]
    offset_velocity: NDArray[np.float64]
    blend_duration: float
    end_velocity: NDArray[np.float64] | None = None
    """When set (the run's last window), a mirrored blend cancels this velocity at ``end`` so
    the motion comes to rest exactly at the chunk's final position."""
    end_blend_duration: float = 0.0
    """Length of that mirrored blend: never longer than the window, so it leaves the seam alone."""
    extension: float = 0.0
    """Seconds after ``end`` in which the motion, unless the next chunk takes over at ``end``,
    goes on playing the chunk's steps beyond the window at full speed (one step per ``dt``): the
    policy's own plan keeps the arm going while the next chunk is late."""
    runout: float = 0.0
    """Seconds after the extension in which the motion goes on along the chunk's remaining steps
    while slowing to rest at its last one (see ``tail.runout_warp``): a stream whose next chunk is
    later still pauses smoothly instead of stopping dead."""

    @property
    def full_speed_end(self) -> float:
        """When the motion starts slowing down if no chunk follows: the end of the extension."""
        return self.end + self.extension

    @property
    def rest_time(self) -> float:
        """When the motion is at rest if no chunk follows: its end, or the end of the runout."""
        return self.end + self.extension + self.runout

    def evaluate(self, at: NDArray[np.floating[Any]]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Positions, velocities and accelerations (each (M, J)) at clock times ``at``."""
        times = np.atleast_1d(np.asarray(at, dtype=float))
        # The chunk is played at step k(t); inside the window k advances one step per dt.
        k = (times - self.chunk_start) / self.dt
        k_rate = np.full_like(times, 1.0 / self.dt)
        k_accel = np.zeros_like(times)
        if self.runout > 0:
            slowing = self.full_speed_end
            after = times > slowing
            warped = runout_warp((times[after] - slowing) / self.runout, self.runout, self.dt)
            k[after] = (slowing - self.chunk_start) / self.dt + warped[0]
            k_rate[after], k_accel[after] = warped[1], warped[2]
        slope = self.spline(k, nu=1)
        p = self.spline(k)
        v = slope * k_rate[:, None]
        a = self.spline(k, nu=2) * (k_rate * k_rate)[:, None] + slope * k_accel[:, None]
        T = self.blend_duration
        inside = ((times >= self.seam) & (times <= self.seam + T))[:, None]
        bp, bv, ba = blend_offset(self.offset_position, self.offset_velocity, None, T, times - self.seam)
        p = p + bp
        v = v + np.where(inside, bv, 0.0)
        a = a + np.where(inside, ba, 0.0)
        if self.end_velocity is not None:
            # g(t) = c T h(s), s = (end - t) / T: g(end) = 0, g'(end) = -c, g''(end) = 0.
            T = self.end_blend_duration
            s = np.clip((self.end - times) / T, 0.0, 1.0)[:, None]
            near_end = ((times <= self.end) & (times >= self.end - T))[:, None]
            hs, hs1, hs2 = velocity_basis(s)
            c = self.end_velocity[None, :]
            p = p + c * T * hs
            v = v - np.where(near_end, c * hs1, 0.0)
            a = a + np.where(near_end, c * hs2 / T, 0.0)
        return p, v, a

    def at_rest_at_end(self) -> ChunkMotion:
        """The same motion, decelerated so that it ends at rest (for the run's last window)."""
        _, v_end, _ = self.bare().evaluate(np.array([self.end]))
        return replace(self, end_velocity=v_end[0], extension=0.0, runout=0.0,
                       end_blend_duration=max(1e-6, min(self.blend_duration, self.end - self.seam)))

    def chunk_alone(self) -> ChunkMotion:
        """The smoothed chunk over the same window, without the blend into the sent motion
        (nor a stop or runout at the end): what the policy asked for."""
        zero = np.zeros_like(self.offset_position)
        return replace(self.bare(), offset_position=zero, offset_velocity=zero)

    def bare(self) -> ChunkMotion:
        """The window alone: no extension, runout or stop at its end."""
        return replace(self, end_velocity=None, extension=0.0, runout=0.0)

    def with_tail(self, tail: Tail) -> ChunkMotion:
        """The window followed by ``tail`` (the chunk's steps beyond it, then a runout)."""
        return replace(self.bare(), extension=tail.extension_s, runout=tail.runout_s)


def take_over_time(seam_time_s: float, arrival: Arrival | None) -> float:
    """When the goal takes over from the motion the controller plays: at the seam, except that
    the window of a chunk that finds the arm at rest (``arrival`` not None) may start at the
    step the chunk arrived (``at_rest.from_rest_seam``) while its goal takes effect later within
    that step. The arm rests until then, and the blend from rest catches up the fraction of a step."""
    return seam_time_s if arrival is None else max(seam_time_s, arrival.goal_takes_effect_s)


def motion_ends_first(previous: ChunkMotion | None, seam_time_s: float, goal: GoalState) -> bool:
    """Whether the seam comes too late to join the motion the controller still plays (its
    runout included): a seam after its end would be refused. The chunk then waits for it to
    finish and starts from rest (a pause, counted as a stall)."""
    return previous is not None and seam_time_s > previous.rest_time + 1e-9 and goal is not GoalState.ENDED


def state_at(motion: ChunkMotion | None, t: float, rest_position: NDArray[np.float64] | None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Position and velocity of the sent motion at ``t`` (at rest after it ends; at
    ``rest_position`` before the first chunk)."""
    if motion is None:
        assert rest_position is not None, "the arm's position is needed before the first chunk"
        return rest_position, np.zeros(len(rest_position))
    if t > motion.rest_time + 1e-9:  # drained: the arm rests where the motion ended
        p, _, _ = motion.evaluate(np.array([motion.rest_time]))
        return p[0], np.zeros(p.shape[1])
    p, v, _ = motion.evaluate(np.array([t]))
    return p[0], v[0]


def join(previous: ChunkMotion | None, spline: StepSpline, window: Window, grid: StepGrid, takes_over_s: float,
         rest_position: NDArray[np.float64] | None, shaping: ShapingConfig) -> ChunkMotion:
    """The chunk's motion (its fit ``spline``) over ``window``, taking over from the sent motion
    ``previous`` at ``takes_over_s`` (``take_over_time``) where the arm is then."""
    position, velocity = state_at(previous, takes_over_s, rest_position)
    return join_at_seam(spline, shaping.dt, grid.time(window.request_step), takes_over_s, grid.time(window.end_step),
                        position, velocity, nominal_blend_s(window.steps, shaping.dt),
                        max_acceleration=shaping.max_acceleration)
