"""``ExecuteOnJtcWithUpsampling`` (``jtc_upsampling``): chunks published as they arrive to the stock
``joint_trajectory_controller`` with ``positions_upsampling`` (ros2_controllers #2491, #2573).

What a user of ros2_controllers runs (a streamer as ros2_control_demos' example_19): an
observation every ``committed_action_steps`` steps, one request in flight; each arriving chunk is
published at once on the controller's ``~/joint_trajectory`` topic as positions only, untimed,
stamp 0, and the controller (``positions_upsampling.enable``, ``policy_frequency = 1 / dt``) times
point ``i`` at ``(i + 1) * dt`` from its arrival, joins the points by the C2 cubic spline that
starts at the velocity it last commanded and ends at rest (``positions_upsampling``), and merges
that into the trajectory it plays (#2419). The points sent stop at ``total_action_steps`` policy
steps after the first chunk's arrival, where the arm comes to rest. No check of ExecutePolicy's:
what JTC refuses, the simulated JTC refuses (``sim.controllers.jtc.validate_trajectory``), and
the benchmark's probe (``unsafe_points``) counts what the controller commanded.

The simulated JTC has no ``positions_upsampling`` of its own, so the executor applies the
controller's preprocessing (``preprocess_incoming_trajectory``, with the last commanded velocity
of the controller's motion as predicted by its own merge, ``sim.controllers.jtc_trajectory``) and
publishes what the controller's callback hands to its validation. It differs from newest-wins
(``newest_wins``, which reaches the controller as action goals with a spline that starts at the
commanded state and a runout to rest, every knot checked): here the spline runs through the
chunk's points only, ends at rest at the last point, and nothing is checked.
"""
from __future__ import annotations

import numpy as np
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from behaviors.controller_link import controller_topic
from behaviors.execute_policy.timing import goal_takes_effect_s
from behaviors.execute_policy.states import HeldChunk
from runtime.tree.behavior import Status
from runtime.io.bus import Publisher
from runtime.io.timestamps import duration_msg
from sim.controllers.jtc import read_points
from sim.controllers.jtc_trajectory import JtcTrajectory, merge_at_arrival, replace_at_arrival

from .newest_wins import ExecuteNewestWinsOnJtc
from .positions_upsampling import UpsamplingParams, preprocess_incoming_trajectory


class UpsamplingTopic:
    """Positions-only chunks published to a JTC with ``positions_upsampling``, and the motion it
    will play (the same interface as ``jtc_stream.JtcStream``: ``follow``, ``finished``, ``cancel``)."""

    def __init__(self, publisher: Publisher, joints: tuple[str, ...], params: UpsamplingParams) -> None:
        self.publisher, self.joints, self.params = publisher, joints, params
        self.motion: JtcTrajectory | None = None
        self.holding = True
        self.sent = False
        self.now_s = 0.0

    def start(self, now_s: float, position: np.ndarray) -> None:
        self.motion, self.holding, self.sent = JtcTrajectory.hold(now_s, position), True, False

    def publish(self, lands_s: float, positions: np.ndarray) -> None:
        """Publish the rows of ``positions`` (untimed, positions only), as upsampled by the
        controller where it arrives at ``lands_s``, and play them in the prediction."""
        assert self.motion is not None, "start() first"
        chunk = JointTrajectory(joint_names=list(self.joints),
                                points=[JointTrajectoryPoint(positions=[float(v) for v in row]) for row in positions])
        before = self.motion.sample(lands_s)
        upsampled = preprocess_incoming_trajectory(chunk, self.params, before.velocity)
        self.publisher.publish(upsampled)
        points = read_points(upsampled, self.joints)
        if self.holding or len(self.motion.points) < 2:
            self.motion = replace_at_arrival(points, 0.0, lands_s, before)
        else:
            self.motion = merge_at_arrival(self.motion, points, 0.0, lands_s, before)
        self.holding, self.sent = False, True

    def follow(self, now_s: float) -> str | None:
        """The controller holds once its motion has played out (a topic has no result to wait for)."""
        assert self.motion is not None
        self.now_s = now_s
        if not self.holding and now_s >= self.motion.end_time:
            self.motion, self.holding = JtcTrajectory.hold(now_s, self.motion.points.positions[-1]), True
        return None

    @property
    def finished(self) -> bool:
        return self.sent and self.holding

    def cancel(self) -> None:
        """Stop: one point, the commanded position a policy step ahead (JTC refuses an empty trajectory)."""
        if self.motion is None or self.holding:
            return
        hold = self.motion.sample(self.now_s).position
        self.publisher.publish(JointTrajectory(joint_names=list(self.joints), points=[
            JointTrajectoryPoint(positions=[float(v) for v in hold], time_from_start=duration_msg(1.0 / self.params.policy_frequency_hz))]))
        self.holding = True


class ExecuteOnJtcWithUpsampling(ExecuteNewestWinsOnJtc):
    """Benchmark executor: every chunk published on arrival, positions only, to the stock
    joint_trajectory_controller with positions_upsampling; nothing checked (see the module docstring)."""

    description = ("Benchmark executor (benchmarks/executors): chunks published on arrival, positions only, to the stock "
                   "joint_trajectory_controller with positions_upsampling (ros2_controllers #2491, #2573); no checks.")

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.publisher: Publisher | None = None
        """The controller's trajectory topic (beside its action), created on the first run."""

    def initialise(self) -> None:
        super().initialise()
        if self.publisher is None:
            self.publisher = self.context.bus.create_publisher(controller_topic(self.config.controller_action_name, "joint_trajectory"), JointTrajectory)

    def start_run(self, now: float) -> Status | None:
        status = super().start_run(now)  # the controller's kind checked, the first request out
        assert self.publisher is not None
        self.stream = UpsamplingTopic(self.publisher, self.safety.group_joints, UpsamplingParams(True, 1.0 / self.config.dt))
        self.stream.start(now, self.session.rest_position())
        return status

    def take(self, received: HeldChunk, now: float) -> Status | None:
        """Publish the chunk's steps still to play, from its arrival at the controller."""
        config, chunk = self.config, received.chunk
        lands = goal_takes_effect_s(now, self.context.tick_period_s, 0.0)
        if self.first_arrival_s is None:
            self.first_arrival_s = lands
        steps = min(config.total_action_steps - self.played(lands), chunk.steps)
        if steps <= 0:
            return None
        assert isinstance(self.stream, UpsamplingTopic)  # start_run put it there
        self.stream.publish(lands, chunk.arm[:steps])
        self.session.queue_gripper_at(lands + config.dt * np.arange(1, steps + 1), None if chunk.gripper is None else chunk.gripper[:steps])
        return None
