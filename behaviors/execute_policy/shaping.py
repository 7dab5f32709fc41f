"""The chunk's motion: its fit, the motion on the clock, and the samples of it.

Pure functions, no state. A chunk is a list of joint positions, one per policy step of ``dt``
seconds, whose step 0 is the request instant. ``fit_chunk`` smooths it with a cubic smoothing
spline (fixed smoothing, weighted by ``policy_tracking_weight``; no per-chunk cross-validation,
which costs ~90 ms; the solver is ``step_spline``). ``ChunkMotion`` is that spline on the clock
from the seam on, plus the seam blend (``seam``), then the tail or the stop at the window's end
(``tail``). ``densify`` samples a motion at ``num_interpolation_points`` instants: those samples
are what the safety checks see and what the controller receives.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from runtime.motion.samples import Samples
from runtime.motion.seam_blend import blend_offset, velocity_basis

from .step_spline import MIN_SMOOTHING_STEPS, StepSpline, interpolating_polynomial, smoothing_spline
from .tail import runout_warp

if TYPE_CHECKING:
    from .tail import Tail


@dataclass(frozen=True)
class ShapingConfig:
    """The run's settings a chunk's motion is planned with (from ``config.PolicyRunConfig``)."""

    dt: float
    committed_action_steps: int
    policy_tracking_weight: float
    num_interpolation_points: int
    max_acceleration: np.ndarray


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
