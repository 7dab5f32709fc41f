"""``ExecuteWithLeRobotQueue``: LeRobot's async robot client, on the stock JTC.

The client of ``lerobot.async_inference`` keeps a queue of timestepped actions
(``baselines.LeRobotQueue``: its own code where lerobot is installed, else
``baselines.ReimplementedQueue``). Every policy step (``dt``) one action leaves the queue for the
arm; an observation goes out (one request in flight) whenever the queue holds no more than
``chunk_size_threshold`` of a chunk, tagged with the timestep of the last action played; an
arriving chunk's actions for timesteps already played are dropped, those still queued are
aggregated ``0.3 * old + 0.7 * new`` (``weighted_average``), the rest are appended.

On the cell the arm is where the action of each control step puts it, as the baseline takes it:
on every merge the queue's actions (up to ``total_action_steps`` played) go to the
``joint_trajectory_controller`` as knots one step apart from the next control step on
(``jtc_stream``), so that between merges the arm plays one action per step, and comes to rest
at the last one when the queue runs dry (a stall: the robot holds the last action, as LeRobot's
client does; no runout). A knot due before the goal can reach the controller is left out (the
arm heads for the next one). Nothing is checked (the benchmark's probe counts the unsafe points
the controller commands). The run succeeds once
``total_action_steps`` actions have been played and the arm rests. ``baselines.run_lerobot_aggregate``
is the same executor as a pure stream simulation.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from behaviors.execute_policy.timing import goal_takes_effect_s
from behaviors.execute_policy.states import HeldChunk
from runtime.tree.behavior import Status
from runtime.tree.ports import InputPort, PortType, Range

from benchmarks.baselines import lerobot_queue_or_reimplementation

from .base import PORTS
from .jtc_stream import StreamsToJtc

TIME_EPS_S = 1e-9


class ExecuteWithLeRobotQueue(StreamsToJtc):
    """Benchmark executor: LeRobot's async client queue (weighted-average aggregation), one action
    per step to the stock joint_trajectory_controller; nothing checked."""

    runout = False

    ports = PORTS + (
        InputPort("chunk_size_threshold", PortType.FLOAT, 0.5,
                  "Send an observation when the queue holds at most this fraction of a chunk (LeRobot's default 0.5).",
                  valid=Range(0.0, 1.0)),
    )
    description = ("Benchmark executor (benchmarks/executors): LeRobot's async robot client queue with weighted-average "
                   "aggregation, one action per policy step to the stock joint_trajectory_controller.")

    def start_run(self, now: float) -> Status | None:
        # LeRobot's client queue or its reimplementation; ExecuteWithLeRobotRtc puts LeRobot's RTC
        # ActionQueue (another API) here.
        self.queue: Any = lerobot_queue_or_reimplementation(self.get_input("chunk_size_threshold"))
        self.origin_s = now  # control step k at origin + k * dt; step 0 is the observed start
        self.next_step = 1
        self.observed_timestep = 0  # of the request in flight
        self.chunk_steps = 0
        return super().start_run(now)

    def run_summary(self) -> dict[str, Any]:
        summary = super().run_summary()
        summary["bench_executor"]["queue"] = getattr(getattr(self, "queue", None), "implementation", "")
        return summary

    def schedule(self, now: float) -> Status | None:
        total, dt = self.config.total_action_steps, self.config.dt
        while self.origin_s + self.next_step * dt <= now + TIME_EPS_S:  # the control steps due
            if len(self.queue) and self.metrics.steps_executed < total:
                self.queue.pop()
                self.metrics.steps_executed += 1
            elif self.metrics.steps_executed:
                self.metrics.stall_seconds += dt
            self.next_step += 1
        if self.metrics.steps_executed >= total:
            if self.stream.finished:
                return self.session.stop(Status.SUCCESS, f"executed {self.metrics.steps_executed} steps")
        elif not self.session.asking and self.queue.ready(self.chunk_steps or 1, self.get_input("chunk_size_threshold")):
            self.observed_timestep = max(self.queue.latest_action, 0)
            self.session.request(now)
        return None

    def take(self, received: HeldChunk, now: float) -> Status | None:
        """Aggregate the chunk into the queue and send the queue's knots."""
        chunk = received.chunk
        actions = chunk.arm if chunk.gripper is None else np.column_stack([chunk.arm, chunk.gripper])
        self.chunk_steps = max(self.chunk_steps, chunk.steps)
        self.queue.merge(self.observed_timestep, actions)
        self.send_queue(np.array(self.queue.pending()), chunk.gripper is not None, now)
        return None

    def send_queue(self, pending: np.ndarray, has_gripper: bool, now: float) -> None:
        """Send the queued actions ``pending`` (arm columns, then the gripper's when
        ``has_gripper``; up to ``total_action_steps`` played) as knots one step apart from the
        next control step, leaving out those due before the goal reaches the controller."""
        config = self.config
        pending = pending[: config.total_action_steps - self.metrics.steps_executed]
        if not len(pending):
            return
        times = self.origin_s + (self.next_step + np.arange(len(pending))) * config.dt
        lands = goal_takes_effect_s(now, self.context.tick_period_s, 0.0)
        sent = times > lands + TIME_EPS_S
        if not sent.any():
            return
        joints = len(self.safety.group_joints)
        self.send_knots(lands, times[sent], pending[sent, :joints], pending[sent, joints] if has_gripper else None)
