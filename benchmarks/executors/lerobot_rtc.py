"""``ExecuteWithLeRobotRtc`` (``lerobot_rtc``): LeRobot 0.6's rollout with its real-time-chunking
inference engine (``lerobot.rollout.inference.rtc.RTCInferenceEngine``), on the stock JTC.

The engine itself cannot run here: it calls a ``PreTrainedPolicy`` in its own process from a
background thread and times each inference on the wall clock, while the benchmark's policy is a
``GetActionChunk`` service whose delays are simulated on the sim clock. What decides what the
robot plays is LeRobot's own code, driven here step by step on the sim clock as the engine's loop
drives it: its ``ActionQueue`` (``lerobot.policies.rtc``, RTC enabled), its ``LatencyTracker``,
its ``RTCConfig`` and its prefix sizing (``_normalize_prev_actions_length``):

- every policy step (``dt``, the rollout's ``1 / fps``) the robot gets the queue's next action
  (``ActionQueue.get``); an empty queue sends nothing and the arm holds (a stall);
- when no request is in flight and the queue holds at most ``queue_threshold`` actions
  (``RTCInferenceConfig.queue_threshold``, 30), a request goes out with the observation of now,
  the queue's unexecuted policy actions (``get_left_over``, padded or cut to
  ``execution_horizon``) as ``previous_action_chunk`` and ``ceil(max latency seen / dt)`` as its
  frozen prefix (``inference_delay``); ``guidance_horizon`` is ``execution_horizon``;
- an answer's latency is tracked, and the chunk replaces the queue from step
  ``ceil(latency / dt)`` on (``ActionQueue.merge``): the policy's own chunk
  (``policy_action_chunk``, else the chunk itself) as the original actions, the chunk as the
  processed ones.

On the cell, as for LeRobot's async client (``lerobot_queue``): after every merge the queue's
actions go to the ``joint_trajectory_controller`` as knots one step apart from the next control
step, no runout, nothing checked. The run succeeds once ``total_action_steps`` actions have been
played and the arm rests.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from behaviors.execute_policy.policy_link import Carryover
from behaviors.execute_policy.states import HeldChunk
from runtime.tree.behavior import Status
from runtime.tree.ports import InputPort, PortType, Range

from .base import PORTS
from .jtc_stream import StreamsToJtc
from .lerobot_queue import TIME_EPS_S, ExecuteWithLeRobotQueue


def lerobot_rtc() -> Any:
    """LeRobot's RTC parts (``lerobot.policies.rtc`` and the engine's prefix sizing), offline."""
    from policy.lerobot_offline import force_offline

    force_offline()
    import lerobot.policies.rtc as rtc
    from lerobot.rollout.inference.rtc import _normalize_prev_actions_length

    return rtc, _normalize_prev_actions_length


class ExecuteWithLeRobotRtc(ExecuteWithLeRobotQueue):
    """Benchmark executor: LeRobot 0.6's rollout RTC engine's queue and timing on the sim clock
    (see the module docstring), one action per step to the stock joint_trajectory_controller."""

    ports = PORTS + (
        InputPort("queue_threshold", PortType.INT, 30, "Ask for a chunk when the queue holds at most this many actions (LeRobot's 30).",
                  valid=Range(0, 10_000)),
        InputPort("execution_horizon", PortType.INT, 10, "RTCConfig.execution_horizon: the prefix length sent back (LeRobot's 10).",
                  valid=Range(1, 10_000)),
    )
    description = ("Benchmark executor (benchmarks/executors): LeRobot 0.6's rollout real-time-chunking engine (its ActionQueue, "
                   "LatencyTracker and RTCConfig) on the sim clock, one action per policy step to the stock joint_trajectory_controller.")
    reads_policy_chunk = True

    def start_run(self, now: float) -> Status | None:
        rtc, self.prefix_length = lerobot_rtc()
        self.rtc_config = rtc.RTCConfig(enabled=True, execution_horizon=self.get_input("execution_horizon"))
        self.origin_s = now  # control step k at origin + k * dt
        self.next_step = 1
        status = StreamsToJtc.start_run(self, now)  # not the async client's queue: the engine's
        self.queue = rtc.ActionQueue(self.rtc_config)
        self.latency = rtc.LatencyTracker()
        self.index_before = 0  # the queue's index when the request in flight went out
        self.anchor: Any = None  # the state sent with the request of the chunk in the queue
        return status

    def run_summary(self) -> dict[str, Any]:
        summary = super().run_summary()
        summary["bench_executor"]["queue"] = "lerobot (policies.rtc.ActionQueue, RTC enabled)"
        return summary

    def schedule(self, now: float) -> Status | None:
        total, dt = self.config.total_action_steps, self.config.dt
        while self.origin_s + self.next_step * dt <= now + TIME_EPS_S:  # the control steps due
            if self.metrics.steps_executed < total and self.queue.get() is not None:
                self.metrics.steps_executed += 1
            elif self.metrics.steps_executed:
                self.metrics.stall_seconds += dt
            self.next_step += 1
        if self.metrics.steps_executed >= total:
            if self.stream.finished:
                return self.session.stop(Status.SUCCESS, f"executed {self.metrics.steps_executed} steps")
        elif not self.session.asking and self.queue.qsize() <= self.get_input("queue_threshold"):
            self.ask_rtc(now)
        return None

    def ask_rtc(self, now: float) -> None:
        """A request as the engine's loop makes it: the leftover and the delay of the worst latency."""
        self.index_before = self.queue.get_action_index()
        leftover = self.queue.get_left_over()
        worst = self.latency.max()
        delay = math.ceil(worst / self.config.dt) if worst else 0
        config = dataclasses.replace(self.config, policy_uses_real_time_chunking=True, guidance_horizon=self.rtc_config.execution_horizon)
        if leftover is not None and len(leftover):
            prefix = self.prefix_length(leftover, target_steps=self.rtc_config.execution_horizon)
            self.session.policy.carryover = Carryover(prefix.numpy(), 0, self.anchor)
        else:
            self.session.policy.carryover = None
        self.session.request(now, frozen=delay, config=config)

    def take(self, received: HeldChunk, now: float) -> Status | None:
        """Merge the chunk into the queue from its delay on, and send the queue's knots."""
        import torch

        chunk = received.chunk
        latency_s = now - received.flight.sent_at_s
        self.latency.add(latency_s)
        processed = chunk.arm if chunk.gripper is None else np.column_stack([chunk.arm, chunk.gripper])
        original = received.policy_chunk if received.policy_chunk is not None else processed
        self.queue.merge(torch.from_numpy(np.array(original, dtype=np.float32)), torch.from_numpy(np.array(processed, dtype=np.float64)),
                         math.ceil(latency_s / self.config.dt - TIME_EPS_S), self.index_before)
        self.anchor = received.flight.anchor
        self.send_queue(self.queue.get_processed_left_over().numpy(), chunk.gripper is not None, now)
        return None
