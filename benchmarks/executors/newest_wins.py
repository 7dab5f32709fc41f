"""``ExecuteNewestWinsOnJtc``: each arriving chunk wins at once, merged by the stock JTC.

ros2_controllers' way of running a VLA (a streamer publishing positions-only chunks to a
``joint_trajectory_controller`` with ``positions_upsampling``, ros2_controllers #2491, as
ros2_control_demos' example_19 does): an observation every ``committed_action_steps`` steps, one
request in flight; each arriving chunk is sent at once as a goal whose step ``i`` is timed
``(i + 1) * dt`` from its arrival at the controller, with the knot velocities of the cubic spline
through the steps that starts at the commanded velocity (``jtc_stream``), and the controller
merges it into the trajectory it plays at that instant (#2419). The steps sent stop at
``total_action_steps`` policy steps after the first chunk's arrival, where the arm comes to rest.
The knots end in a runout to rest (``jtc_stream.runout_knots``); nothing is checked (the
benchmark's probe counts the unsafe points the controller commands). ``baselines.run_jtc_newest_wins`` is
the same executor as a pure stream simulation.
"""
from __future__ import annotations

import math

import numpy as np

from behaviors.execute_policy.timing import goal_takes_effect_s
from behaviors.execute_policy.states import HeldChunk
from runtime.tree.behavior import Status

from .jtc_stream import StreamsToJtc


class ExecuteNewestWinsOnJtc(StreamsToJtc):
    """Benchmark executor: every chunk replaces the rest of the motion on arrival, merged by the
    stock joint_trajectory_controller; nothing checked."""

    description = ("Benchmark executor (benchmarks/executors): newest chunk wins, sent on arrival to the stock "
                   "joint_trajectory_controller, timed (i+1)*dt from its arrival and merged by the controller.")

    def start_run(self, now: float) -> Status | None:
        self.first_arrival_s: float | None = None  # the steps are counted from the first chunk's arrival
        self.asked_s = now
        return super().start_run(now)

    def played(self, t: float) -> int:
        """Policy steps played by ``t`` (at most ``total_action_steps``)."""
        if self.first_arrival_s is None:
            return 0
        return min(self.config.total_action_steps, max(0, math.floor((t - self.first_arrival_s) / self.config.dt + 1e-9)))

    def schedule(self, now: float) -> Status | None:
        self.metrics.steps_executed = self.played(now)
        config = self.config
        if self.metrics.steps_executed >= config.total_action_steps:
            if not self.session.asking and self.stream.finished:
                return self.session.stop(Status.SUCCESS, f"executed {self.metrics.steps_executed} steps")
        elif not self.session.asking and now + 1e-9 >= self.asked_s + config.committed_action_steps * config.dt:
            self.asked_s = now
            self.session.request(now)
        return None

    def take(self, received: HeldChunk, now: float) -> Status | None:
        """Send the chunk from its arrival at the controller."""
        config, chunk = self.config, received.chunk
        lands = goal_takes_effect_s(now, self.context.tick_period_s, 0.0)
        if self.first_arrival_s is None:
            self.first_arrival_s = lands
        steps = min(config.total_action_steps - self.played(lands), chunk.steps)
        if steps <= 0:
            return None
        times = lands + config.dt * np.arange(1, steps + 1)
        self.send_knots(lands, times, chunk.arm[:steps], None if chunk.gripper is None else chunk.gripper[:steps])
        return None
