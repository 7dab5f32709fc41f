"""ros2_controllers' ``positions_upsampling`` of the ``joint_trajectory_controller``: what JTC does
to a positions-only ``trajectory_msgs/JointTrajectory`` that arrives on its ``~/joint_trajectory``
topic before it validates it (ros2_controllers #2491, merged 2026-08-18, with the cross-chunk
velocity continuity of #2573). #2491 is modelled from its merged source and tested with its own
test cases (``tests/test_positions_upsampling.py``); the stored snapshot of ros2_controllers ends
at #2491, so #2573 is modelled from its pull request's description (the first knot's velocity
clamped to the last commanded one, the last knot at rest), its own test cases not ported.

With ``positions_upsampling.enable`` and an interpolation method other than ``none``, a message
whose every point carries positions and neither velocities nor accelerations is

1. timed, when every ``time_from_start`` is zero and ``policy_frequency`` is above zero: point
   ``i`` at ``(i + 1) / policy_frequency`` (the first one a policy step ahead, so the controller
   ramps into the chunk from its state instead of stepping to it; ``synthesize_timing``);
2. given the knot velocities of the global C2 cubic spline through its points
   (``fill_cubic_spline_velocities``): acceleration continuous at every interior knot, the last
   knot at rest, the first knot at ``start_velocity``: zero in #2491 (rest at both ends), the
   velocity the controller last commanded in #2573 (its snapshot of the last commanded state,
   #2564), so that a stream of chunks plans no stop at every seam.

JTC's cubic Hermite sampler then plays that spline. Every other message passes unchanged: one
that carries velocities or accelerations, and every message when the feature is off. Only the
topic is upsampled, never a ``FollowJointTrajectory`` goal. A trajectory the solve cannot take
(fewer than two points, points of different widths, times not strictly increasing) is left as it
came, for JTC's validation to refuse.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from trajectory_msgs.msg import JointTrajectory

from runtime.io.timestamps import duration_msg, to_seconds

from benchmarks.baselines import cubic_spline_velocities


@dataclass(frozen=True)
class UpsamplingParams:
    """JTC's ``positions_upsampling.*`` parameters (its defaults: off, no synthesized timing)."""

    enable: bool = False
    policy_frequency_hz: float = 0.0
    """Points of an untimed chunk are ``1 / policy_frequency_hz`` apart; 0: chunks carry their timing."""
    interpolation_none: bool = False
    """JTC's ``interpolation_method`` is ``none``: upsampling has no effect."""


def fill_cubic_spline_velocities(times_s: np.ndarray, positions: np.ndarray, start_velocity: np.ndarray | None = None) -> np.ndarray | None:
    """The knot velocities (N x J) of the C2 cubic spline through ``positions`` (N x J) at
    ``times_s``, starting at ``start_velocity`` (None: at rest) and ending at rest; None where JTC
    leaves the trajectory untouched (fewer than two points, no joints, times not strictly increasing)."""
    positions = np.asarray(positions, dtype=float)
    times = np.asarray(times_s, dtype=float)
    if positions.ndim != 2 or len(positions) < 2 or positions.shape[1] == 0 or len(times) != len(positions):
        return None
    if np.any(np.diff(times) <= 0.0):
        return None
    start = np.zeros(positions.shape[1]) if start_velocity is None else np.asarray(start_velocity, dtype=float)
    return cubic_spline_velocities(times, positions, start)


def is_positions_only(msg: JointTrajectory) -> bool:
    """Every point carries positions and neither velocities nor accelerations (and there is one)."""
    return bool(msg.points) and all(len(p.positions) and not len(p.velocities) and not len(p.accelerations) for p in msg.points)


def synthesize_timing(msg: JointTrajectory, policy_frequency_hz: float) -> JointTrajectory:
    """``msg`` with point ``i`` at ``(i + 1) / policy_frequency_hz`` when it carries no timing
    (every ``time_from_start`` zero) and the frequency is above zero; else ``msg`` itself."""
    if policy_frequency_hz <= 0.0 or any(to_seconds(p.time_from_start) != 0.0 for p in msg.points):
        return msg
    timed = copy.deepcopy(msg)
    for i, point in enumerate(timed.points):
        point.time_from_start = duration_msg((i + 1) / policy_frequency_hz)
    return timed


def with_spline_velocities(msg: JointTrajectory, start_velocity: np.ndarray | None = None) -> JointTrajectory:
    """``msg`` with the spline's knot velocities (``fill_cubic_spline_velocities``) written into
    its points; ``msg`` itself where the solve leaves it untouched (also points of different widths)."""
    widths = {len(p.positions) for p in msg.points}
    if len(widths) != 1:
        return msg
    times = np.array([to_seconds(p.time_from_start) for p in msg.points])
    velocities = fill_cubic_spline_velocities(times, np.array([list(p.positions) for p in msg.points]), start_velocity)
    if velocities is None:
        return msg
    filled = copy.deepcopy(msg)
    for point, row in zip(filled.points, velocities):
        point.velocities = row.tolist()
    return filled


def preprocess_incoming_trajectory(msg: JointTrajectory, params: UpsamplingParams, last_commanded_velocity: np.ndarray | None) -> JointTrajectory:
    """What JTC's topic callback makes of ``msg`` before validating it (the module docstring):
    ``last_commanded_velocity`` (in the message's joint order) is the first knot's velocity
    (#2573); None starts it at rest (#2491 alone). Never changes the header (its stamp)."""
    if not params.enable or params.interpolation_none or not is_positions_only(msg):
        return msg
    return with_spline_velocities(synthesize_timing(msg, params.policy_frequency_hz), last_commanded_velocity)
