"""From a policy chunk to a smooth, densified motion that joins the sent one at the seam.

Pure functions, no state. A chunk is a list of joint positions, one per policy step of ``dt``
seconds, whose step 0 is the request instant. ``fit_chunk`` smooths it with a cubic smoothing
spline (fixed smoothing, weighted by ``policy_tracking_weight``; no per-chunk cross-validation,
which costs ~90 ms). ``ChunkMotion`` is that spline from the seam on, plus a blend offset that
starts at the difference between the sent motion and the spline at the seam (position and
velocity) and decays to zero with zero slope and curvature at both ends, so the motion is C1 at
every seam. ``densify`` samples a motion at ``num_interpolation_points`` instants: those samples
are what the safety checks see and what the controller receives.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from runtime.motion import seam_blend
from runtime.motion.samples import Samples
from runtime.motion.seam_blend import blend_offset, velocity_basis

from .step_spline import MIN_SMOOTHING_STEPS, StepSpline, interpolating_polynomial, smoothing_spline


def fit_chunk(positions: np.ndarray, tracking_weight: float) -> StepSpline:
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


@dataclass(frozen=True)
class ChunkMotion:
    """One chunk's motion on the clock: the smoothed chunk plus the seam blend.

    ``chunk_start`` is the clock time of the chunk's step 0 (the request instant); the motion
    is defined on ``[seam, end]``.
    """

    spline: StepSpline
    dt: float
    chunk_start: float
    seam: float
    end: float
    offset_position: np.ndarray
    offset_velocity: np.ndarray
    blend_duration: float
    end_velocity: np.ndarray | None = None
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
    while slowing to rest at its last one (see ``runout_warp``): a stream whose next chunk is
    later still pauses smoothly instead of stopping dead."""

    @property
    def full_speed_end(self) -> float:
        """When the motion starts slowing down if no chunk follows: the end of the extension."""
        return self.end + self.extension

    @property
    def rest_time(self) -> float:
        """When the motion is at rest if no chunk follows: its end, or the end of the runout."""
        return self.end + self.extension + self.runout

    def evaluate(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities and accelerations (each (M, J)) at clock ``times``."""
        times = np.atleast_1d(np.asarray(times, dtype=float))
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
        bp, bv, ba = blend_offset(self.offset_position, self.offset_velocity, np.zeros_like(self.offset_position), T, times - self.seam)
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


RUNOUT_SLOWDOWN = 2
"""A runout plays the chunk at half speed on average: ``runout / (RUNOUT_SLOWDOWN * dt)`` chunk
steps in ``runout / dt`` run steps."""


def runout_warp(s: np.ndarray, runout: float, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Chunk steps advanced since the window's end, their rate and its rate, at runout fraction ``s``.

    The playback speed falls from one step per ``dt`` to zero as ``1 - (3 s^2 - 2 s^3)``: no
    acceleration step where the runout begins (the speed's slope is zero there) nor where it
    ends, and ``runout / (2 dt)`` steps are covered in all.
    """
    s = np.clip(s, 0.0, 1.0)
    steps = runout / dt * (s - s**3 + 0.5 * s**4)
    rate = (1.0 - 3.0 * s**2 + 2.0 * s**3) / dt
    rate_of_rate = (-6.0 * s + 6.0 * s**2) / (runout * dt)
    return steps, rate, rate_of_rate


def runout_duration(end_velocity: np.ndarray, max_acceleration: np.ndarray, dt: float, nominal: float, spare_steps: int) -> float:
    """Length of the runout after a window that ends at ``end_velocity``: ``nominal`` seconds,
    longer if that would brake harder than half of ``max_acceleration`` (the warp peaks at
    1.5 v / runout), in whole pairs of ``dt`` so the runout covers whole chunk steps. Zero when
    the chunk has fewer than the needed ``spare_steps`` beyond the window: it says nothing about
    where to go."""
    speed = np.abs(np.asarray(end_velocity, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        needed = float(np.max(np.where(speed > 0, 3.0 * speed / np.asarray(max_acceleration, dtype=float), 0.0), initial=0.0))
    steps = math.ceil(max(nominal, needed) / (RUNOUT_SLOWDOWN * dt) - 1e-9)
    if steps < 1 or steps > spare_steps:
        return 0.0
    return RUNOUT_SLOWDOWN * dt * steps


def runout_chunk_steps(runout_s: float, dt: float) -> int:
    """Chunk steps a runout of ``runout_s`` seconds covers (it takes ``RUNOUT_SLOWDOWN`` run steps each)."""
    return round(runout_s / (RUNOUT_SLOWDOWN * dt))


@dataclass(frozen=True)
class Tail:
    """What follows a window when the next chunk is late: ``extension_steps`` of the chunk's
    steps beyond the window at full speed, then a runout of ``runout_s`` seconds over its last
    ``runout_steps`` steps, ending at rest."""

    extension_steps: int
    runout_steps: int
    dt: float

    @property
    def extension_s(self) -> float:
        return self.extension_steps * self.dt

    @property
    def runout_s(self) -> float:
        return RUNOUT_SLOWDOWN * self.dt * self.runout_steps

    @property
    def steps(self) -> int:
        """Chunk steps the tail covers in all."""
        return self.extension_steps + self.runout_steps


NO_TAIL = Tail(0, 0, 1.0)


def plan_tail(peak_velocity: np.ndarray, max_acceleration: np.ndarray, dt: float, nominal_runout_s: float, spare_steps: int) -> Tail:
    """The tail over the ``spare_steps`` chunk steps beyond a window, the fastest of which move
    at ``peak_velocity``: the runout (``runout_duration``, braking from that speed) takes the
    last steps, so the motion comes to rest at the chunk's last step, and the steps before it
    are played at full speed. No tail when the spare steps cannot hold a runout."""
    runout = runout_duration(peak_velocity, max_acceleration, dt, nominal_runout_s, spare_steps)
    if runout <= 0:
        return NO_TAIL
    runout_steps = runout_chunk_steps(runout, dt)
    return Tail(spare_steps - runout_steps, runout_steps, dt)


BLEND_SHARE = 0.5
"""The blend may use this share of the acceleration the chunk's own motion leaves free (half,
as the runout brakes with half the limit): a long way to join is covered gently."""


def chunk_acceleration_peak(spline: StepSpline, dt: float, from_step: float) -> np.ndarray:
    """Per joint, the largest acceleration (rad/s^2) of the smoothed chunk from ``from_step`` to
    its last step. Its second derivative is piecewise linear between the integer steps (the
    knots), so the steps and ``from_step`` are where it peaks."""
    last = spline.last_step
    steps = np.unique(np.concatenate([[min(from_step, last)], np.arange(math.ceil(from_step), math.floor(last) + 1)]))
    return np.abs(np.atleast_2d(spline(steps, nu=2))).max(axis=0) / (dt * dt)


def join_at_seam(
    spline: StepSpline,
    dt: float,
    chunk_start: float,
    seam: float,
    end: float,
    sent_position: np.ndarray,
    sent_velocity: np.ndarray,
    blend_duration: float,
    max_acceleration: np.ndarray | None = None,
) -> ChunkMotion:
    """The chunk's motion from ``seam`` to ``end``, continuous in position and velocity with
    the sent motion's state (``sent_position``, ``sent_velocity``) at the seam.

    The offset between the two is blended out (``runtime.motion.seam_blend``) over ``blend_duration``
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
        blend_duration = seam_blend.blend_duration(offset_p, offset_v, BLEND_SHARE * headroom, blend_duration)
    return ChunkMotion(spline, dt, chunk_start, seam, end, offset_p, offset_v, max(blend_duration, 1e-6))


MAX_SAMPLE_SPACING = 0.01
"""Seconds. Samples are never sparser than this, whatever ``num_interpolation_points`` says: the
checks see only the samples, and the controller interpolates between them, so a sparse window
could hide an over-speed between two points that are each within the limits."""


def densify(motion: ChunkMotion, num_points: int) -> Samples:
    """At least ``num_points`` evenly spaced samples from the seam to the end of the window
    (inclusive), and no more than ``MAX_SAMPLE_SPACING`` apart; then the extension and the
    runout, if any, at that spacing (the window's end stays a sample: the next seam)."""
    needed = int(np.ceil((motion.end - motion.seam) / MAX_SAMPLE_SPACING - 1e-9)) + 1
    times = np.linspace(motion.seam, motion.end, max(2, num_points, needed))
    tail_s = motion.rest_time - motion.end
    if tail_s > 0:
        count = int(np.ceil(tail_s / MAX_SAMPLE_SPACING - 1e-9))
        times = np.concatenate([times, motion.end + tail_s * np.arange(1, count + 1) / count])
    p, v, a = motion.evaluate(times)
    return Samples(times, p, v, a)
